"""How a benchmark script ends: a :class:`~geoscaler.errors.GeoscalerError` (a path without
meshes, a file that is no mesh) is said in one line with exit status 2, as the command line
says it, not as a traceback."""

from __future__ import annotations

import sys
from collections.abc import Callable

from geoscaler.errors import GeoscalerError


def exit_status(main: Callable[[], int | None]) -> int:
    """``main()``'s exit status (None: 0), or 2 where it raised a GeoscalerError."""
    try:
        return main() or 0
    except GeoscalerError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
