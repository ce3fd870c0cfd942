"""What the user chooses and is told in the app's UI, as one dataclass.

The panels read and write :class:`AppState` (``app.state``) instead of attributes of
:class:`~geoscaler.app.main.App`; App acts on it (starts the optimiser with ``settings``, exports
to ``export_name``) and reports back through ``error`` and ``messages``. Per-window display
details that no one else reads (a slider's position, a plot's x axis) stay in their panel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .training import TrainingSettings
from .views import SIDE_BY_SIDE


@dataclass
class AppState:
    """The UI-editable state of the app.

    Attributes:
        settings: the optimiser's next run: method, scale, steps, time budget, validation views
            (the Optimise window edits them; a run starts with a copy).
        export_name: the mesh file the Export window writes.
        overwrite: whether an export may replace existing files.
        open_path: the path typed in File > Open path.
        error: the error line shown in the Optimise window (None: no error).
        messages: what the app reports (opened, wrote ...), newest last.
        view_mode: how the Views window shows the two views, an index into
            :data:`geoscaler.app.views.MODES`.
        bookmark: the index of the selected bookmark (-1: none).
        lit: the views show every map lit (protocol 2) instead of the base colour unlit.
    """

    settings: TrainingSettings = field(default_factory=TrainingSettings)
    export_name: str = ""
    overwrite: bool = False
    open_path: str = ""
    error: str | None = None
    messages: list[str] = field(default_factory=list)
    view_mode: int = SIDE_BY_SIDE
    bookmark: int = -1
    lit: bool = False
