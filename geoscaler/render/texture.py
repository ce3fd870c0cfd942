"""Texture filtering as a GPU does it for an sRGB base-colour map (PROTOCOL.md).

Texels are decoded from 8-bit sRGB to linear light, a mip chain of 2 x 2 box averages is built
in linear light, and samples are filtered trilinearly with an isotropic level of detail taken
from the screen-space UV Jacobian, with repeat addressing and texel centres at (i + 0.5) / size.
Everything is differentiable with respect to the texels and the UVs.

Textures are ``(H, W, C)`` tensors, row 0 at the top of the image; UVs follow the OpenGL
convention of :mod:`geoscaler.mesh` (``v = 0`` at the bottom row).
"""

from __future__ import annotations

import warnings
from functools import cached_property
from typing import NamedTuple

import numpy as np
import scipy.sparse
import torch
import torch.nn.functional as F

from geoscaler.render.devices import tensor_bytes


def mip_sizes(height: int, width: int) -> list[tuple[int, int]]:
    """Level sizes of the mip chain: halve (rounding down, at least 1) until 1 x 1."""
    sizes = [(height, width)]
    while sizes[-1] != (1, 1):
        h, w = sizes[-1]
        sizes.append((max(h // 2, 1), max(w // 2, 1)))
    return sizes


def next_mip_level(above: torch.Tensor) -> torch.Tensor:
    """The mip level below ``above``: each texel the 2 x 2 box average of the texels above it.

    Args:
        above: ``(h, w, C)`` float linear level.

    Returns:
        ``(max(h // 2, 1), max(w // 2, 1), C)``: an odd row or column is dropped when halving;
        a side already at 1 is kept as it is. Rows ``[2 i, 2 j)`` of ``above`` alone give rows
        ``[i, j)`` of the result, to the same bits.
    """
    kernel = (2 if above.shape[0] > 1 else 1, 2 if above.shape[1] > 1 else 1)
    return F.avg_pool2d(above.permute(2, 0, 1)[None], kernel_size=kernel)[0].permute(1, 2, 0)


def build_mip_chain(texture: torch.Tensor) -> list[torch.Tensor]:
    """Mip levels of a linear texture, each the 2 x 2 box average of the one above
    (:func:`next_mip_level`).

    Args:
        texture: ``(H, W, C)`` float linear texture.

    Returns:
        Levels ``(H_l, W_l, C)`` from full size down to 1 x 1, sizes from :func:`mip_sizes`.
    """
    levels = [texture]
    for _ in mip_sizes(*texture.shape[:2])[1:]:
        levels.append(next_mip_level(levels[-1]))
    return levels


class UVFootprint(NamedTuple):
    """Texture coordinates of N screen samples and their derivatives per sample step.

    Each field is ``(N,)``: ``u``, ``v``, then ``d/dx`` (one sample right) and ``d/dy`` (one
    sample down) of each.
    """

    u: torch.Tensor
    v: torch.Tensor
    du_dx: torch.Tensor
    dv_dx: torch.Tensor
    du_dy: torch.Tensor
    dv_dy: torch.Tensor


class MipLayout:
    """Where each level of a mip chain lives in one flat texel table, and which texels a
    filtered lookup reads.

    The filters are expressed as *taps*: texel indices into the flat table and their weights,
    ``(4, N)`` each for bilinear lookups (one :func:`gather`), 4 or 8 a sample for trilinear
    ones (:meth:`trilinear_taps`, which a view folds into a :class:`TapMatrix`). A lookup is a
    weighted sum of its taps whatever the texel values are, so a view whose UVs are fixed can
    cache its taps and re-filter new texels cheaply.

    Args:
        height, width: size of level 0 in texels.
        device: where the index tensors live.
    """

    def __init__(self, height: int, width: int, device: torch.device | str = "cpu"):
        sizes = torch.tensor(mip_sizes(height, width), dtype=torch.long)
        counts = sizes[:, 0] * sizes[:, 1]
        self.size = (height, width)
        self.num_levels = len(sizes)
        self.num_texels = int(counts.sum())
        if self.num_texels >= 2**31:
            raise ValueError(f"a {height} x {width} mip chain has too many texels to index")
        # Per-level tables, int32 like the taps: half the memory traffic of int64.
        self.heights = sizes[:, 0].to(device, torch.int32)
        self.widths = sizes[:, 1].to(device, torch.int32)
        self.offsets = (torch.cumsum(counts, 0) - counts).to(device, torch.int32)

    def bilinear_taps(
        self, u: torch.Tensor, v: torch.Tensor, level: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The 4 taps of bilinear filtering at integer mip ``level``, repeat addressing.

        Args:
            u, v: ``(N,)`` float texture coordinates (texel centres at (i + 0.5) / size).
            level: ``(N,)`` int32 or int64 mip level per sample, in ``[0, num_levels)``.

        Returns:
            ``(index, weight)``, each ``(4, N)``: int32 texels (x0, y0), (x1, y0), (x0, y1),
            (x1, y1) and float weights.
        """
        height = self.heights.index_select(0, level)
        width = self.widths.index_select(0, level)
        x = u * width - 0.5
        y = (1.0 - v) * height - 0.5
        x0, y0 = torch.floor(x), torch.floor(y)
        fx, fy = x - x0, y - y0
        # The two columns and two rows read, (2, N) each. Repeat addressing on whole-number
        # floats: remainder is fmod there, exact, and vectorised, unlike an integer division.
        cols = torch.remainder(torch.stack([x0, x0 + 1]), width).int()
        rows = torch.remainder(torch.stack([y0, y0 + 1]), height).int() * width
        rows += self.offsets.index_select(0, level)
        index = (rows[:, None] + cols[None]).view(4, -1)
        weight = torch.stack([1 - fy, fy])[:, None] * torch.stack([1 - fx, fx])[None]
        return index, weight.view(4, -1)

    def level_of_detail(
        self, du_dx: torch.Tensor, dv_dx: torch.Tensor, du_dy: torch.Tensor, dv_dy: torch.Tensor
    ) -> torch.Tensor:
        """Isotropic LOD: log2 of the larger singular value of the UV Jacobian in texels.

        Args:
            du_dx, dv_dx, du_dy, dv_dy: ``(N,)`` UV derivatives per screen sample step.

        Returns:
            ``(N,)`` unclamped level of detail (negative where texels are magnified).
        """
        height, width = self.size
        a, c = du_dx * width, dv_dx * height
        b, d = du_dy * width, dv_dy * height
        frobenius = a * a + b * b + c * c + d * d
        det = a * d - b * c
        gap = (frobenius * frobenius - 4 * det * det).clamp_min(1e-20).sqrt()
        sigma_max_sq = (0.5 * (frobenius + gap)).clamp_min(1e-30)
        return 0.5 * torch.log2(sigma_max_sq)

    def levels(self, lod: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(fine, coarse, blend)``, each ``(N,)``: the two int32 mip levels around ``lod``
        (clamped to ``[0, num_levels - 1]``) and the weight of the coarser one."""
        lod = lod.clamp(0.0, float(self.num_levels - 1))
        fine = torch.floor(lod)
        coarse = (fine + 1).clamp_max(self.num_levels - 1)
        return fine.int(), coarse.int(), lod - fine

    def trilinear_taps(
        self, u: torch.Tensor, v: torch.Tensor, lod: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The taps of trilinear filtering: bilinear on the two levels around ``lod``.

        Args:
            u, v: ``(N,)`` texture coordinates.
            lod: ``(N,)`` level of detail, clamped here to ``[0, num_levels - 1]``.

        Returns:
            ``(count, index, weight)``: ``(N,)`` int32 taps of each sample, 4 where the coarser
            level has no weight (magnified samples, most of a typical view's: that level is
            not computed there) and 8 elsewhere; ``(E,)`` int32 texels and float weights,
            sample by sample, the finer level's 4 taps before the coarser's.
        """
        fine, coarse, blended = self._level_taps(u, v, lod)
        fine_index, fine_weight = (t.T.reshape(-1) for t in fine)  # sample-major
        count = torch.full((len(u),), 4, dtype=torch.int32, device=u.device)
        if coarse is None:
            return count, fine_index, fine_weight
        coarse_index, coarse_weight = coarse
        count.index_fill_(0, blended, 8)
        first = torch.cumsum(count, 0, dtype=torch.int64) - count  # each sample's first tap
        four = torch.arange(4, device=lod.device)
        fine_at = (first[:, None] + four).view(-1)
        coarse_at = (first.index_select(0, blended)[:, None] + 4 + four).view(-1)
        index = fine_index.new_empty(len(fine_index) + len(coarse_at))
        weight = fine_weight.new_empty(len(index))
        index.index_copy_(0, fine_at, fine_index)
        index.index_copy_(0, coarse_at, coarse_index.T.reshape(-1))
        weight.index_copy_(0, fine_at, fine_weight)
        weight.index_copy_(0, coarse_at, coarse_weight.T.reshape(-1))
        return count, index, weight

    def taps_of_rows(
        self, footprint: UVFootprint, row: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The taps of :meth:`taps`, each with the row its sample is summed into, level by
        level instead of sample by sample: the finer level's 4 taps of every sample, then the
        coarser level's of the samples that weigh it. For :meth:`TapMatrix.merged`, which
        takes taps in any order: interleaving the two levels' taps sample by sample (two
        scattering copies and the transposes) took about a fifth of a view's taps.

        Args:
            footprint: ``N`` samples.
            row: ``(N,)`` int32 row of each sample.

        Returns:
            ``(row, texel, weight)``, each ``(E,)``: int32 row and texel, float weight.
        """
        lod = self.level_of_detail(
            footprint.du_dx, footprint.dv_dx, footprint.du_dy, footprint.dv_dy
        )
        fine, coarse, blended = self._level_taps(footprint.u, footprint.v, lod)
        rows, levels = [row.expand(4, -1)], [fine]
        if coarse is not None:
            rows.append(row.index_select(0, blended).expand(4, -1))
            levels.append(coarse)
        return (
            torch.cat([r.reshape(-1) for r in rows]),
            torch.cat([index.reshape(-1) for index, _ in levels]),
            torch.cat([weight.reshape(-1) for _, weight in levels]),
        )

    def _level_taps(
        self, u: torch.Tensor, v: torch.Tensor, lod: torch.Tensor
    ) -> tuple[
        tuple[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor] | None, torch.Tensor
    ]:
        """Trilinear filtering's taps per level: ``((4, N) index and weight on the finer
        level of every sample, the same ``(4, B)`` pair on the coarser level of the ``(B,)``
        samples ``blended`` that weigh it (None where none does), blended)``; the weights
        include the levels' blend."""
        fine, coarse, blend = self.levels(lod)
        fine_index, fine_weight = self.bilinear_taps(u, v, fine)  # (4, N) each
        fine_taps = (fine_index, fine_weight * (1 - blend))
        blended = torch.nonzero(blend > 0).squeeze(1)
        if len(blended) == 0:
            return fine_taps, None, blended
        u, v, coarse, blend = (t.index_select(0, blended) for t in (u, v, coarse, blend))
        coarse_index, coarse_weight = self.bilinear_taps(u, v, coarse)
        return fine_taps, (coarse_index, coarse_weight * blend), blended

    def taps(self, footprint: UVFootprint) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Trilinear taps of a GPU-style lookup of every sample of ``footprint``: ``(count,
        index, weight)`` (:meth:`trilinear_taps`)."""
        lod = self.level_of_detail(
            footprint.du_dx, footprint.dv_dx, footprint.du_dy, footprint.dv_dy
        )
        return self.trilinear_taps(footprint.u, footprint.v, lod)


def gather(texels: torch.Tensor, index: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Filter a flat texel table with taps.

    Args:
        texels: ``(C, T)`` flat mip chain.
        index, weight: ``(K, N)`` taps.

    Returns:
        ``(C, N)``: ``sum_k weight[k] * texels[:, index[k]]``.
    """
    flat = index.reshape(-1)
    return torch.stack([_weighted_sum(row.index_select(0, flat), weight) for row in texels])


def _weighted_sum(values: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``(N,)`` ``sum_k weight[k] * values[k]``, where ``values`` are the ``(K N,)`` texels
    gathered for ``(K, N)`` taps: one fused multiply-add per tap, no ``(K, N)`` product."""
    values = values.view(weight.shape)
    result = values[0] * weight[0]
    for k in range(1, len(weight)):
        result = torch.addcmul(result, values[k], weight[k])
    return result


def take(table: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``(C, M)`` columns ``index`` of a ``(C, T)`` table.

    One 1-D ``index_select`` per channel: on the CPU its backward (a 1-D ``index_add``) is
    about 9 times faster than that of a single ``index_select`` along dim 1.
    """
    return torch.stack([row.index_select(0, index) for row in table])


class TapMatrix:
    """Fixed texture lookups as one sparse ``(R, T)`` matrix: output ``r`` is the sum of
    ``weight * table[texel]`` over the taps of row ``r``.

    With fixed UVs every rendered pixel is such a sum over texels of the candidate's mip
    chain, so a render is a sparse-dense product, and its gradient the product with the
    transpose (CSR both, int32 indices; the transpose is made at the first backward pass, so
    views that are only ever scored never pay for it). On the CPU the pair is about 10 times
    faster than gathering the taps and adding them up per pixel (``index_select`` /
    ``index_add``), forward and backward.

    Args:
        row, texel: ``(M,)`` int32 row (output) and texel of each tap, in any order (sorted
            by row is quickest); repeated pairs add up.
        weight: ``(M,)`` float weights.
        shape: ``(R, T)``: outputs and texels of the flat mip chain.
    """

    def __init__(
        self, row: torch.Tensor, texel: torch.Tensor, weight: torch.Tensor, shape: tuple[int, int]
    ):
        self.shape = shape
        self.matrix = _csr(row, texel, weight, shape)

    @classmethod
    def by_rows(
        cls, counts: torch.Tensor, texel: torch.Tensor, weight: torch.Tensor, shape: tuple[int, int]
    ) -> TapMatrix:
        """Taps already in row order: ``(R,)`` how many taps each row has, then ``(M,)`` their
        texels and weights, row 0's first (nothing to sort or count)."""
        taps = cls.__new__(cls)
        taps.shape = shape
        taps.matrix = _csr_by_rows(counts, texel, weight, shape)
        return taps

    @classmethod
    def merged(
        cls, row: torch.Tensor, texel: torch.Tensor, weight: torch.Tensor, shape: tuple[int, int]
    ) -> TapMatrix:
        """A matrix of ``(M,)`` taps given by ``row``, in any order, each row's taps of one
        texel summed into one tap, the row's texels ascending: the samples of a pixel read
        many of the same texels (of its coarser mip level above all), so the matrix holds
        fewer taps and a product with it costs less. Equal to :class:`TapMatrix` of the same
        taps up to float rounding. On the CPU the taps are counted into their rows and each
        row is sorted on its own (scipy: a row holds a few dozen taps), about ten times faster
        than sorting every tap of the view at once, as the GPU does."""
        on_cpu = texel.device.type == "cpu"
        merge = _merged_rows_on_cpu if on_cpu else _merged_rows_by_sorting
        return cls.by_rows(*merge(row, texel, weight, shape), shape)

    @property
    def texel(self) -> torch.Tensor:
        """``(M,)`` int32 texel of every tap, by row."""
        return self.matrix.col_indices()

    @property
    def weight(self) -> torch.Tensor:
        """``(M,)`` weight of every tap, by row."""
        return self.matrix.values()

    @cached_property
    def transposed(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(texels, matrix)``: the ``(U,)`` int32 texels the taps read, ascending, and the
        ``(U, R)`` CSR transpose over them alone (row ``u`` holds texel ``texels[u]``'s taps, in
        row order): what the gradient is a product with. Over the texels read, not the whole
        chain, so that its row offsets do not grow with the texture (over a 2048 x 2048
        candidate's chain they are 22 MB a view)."""
        crow = self.matrix.crow_indices()
        rows = torch.arange(self.shape[0], dtype=torch.int32, device=crow.device)
        row = torch.repeat_interleave(rows, crow.diff())
        order = torch.argsort(self.texel, stable=True)
        texels, counts = torch.unique_consecutive(self.texel[order], return_counts=True)
        shape = (len(texels), self.shape[0])
        return texels, _csr_by_rows(counts, row[order], self.weight[order], shape)

    @property
    def nbytes(self) -> int:
        """Bytes the matrix (and its transpose, once made) hold."""
        parts = [self.matrix.crow_indices(), self.matrix.col_indices(), self.matrix.values()]
        if "transposed" in self.__dict__:
            texels, matrix = self.transposed
            parts += [texels, matrix.crow_indices(), matrix.col_indices(), matrix.values()]
        return tensor_bytes(parts)

    def __call__(self, table: torch.Tensor) -> torch.Tensor:
        """``(R, C)`` outputs of a ``(T, C)`` texel table (differentiable in ``table``)."""
        return _TapProduct.apply(self, table)


# torch warns once that sparse CSR support is in beta (the product used here is not): filtered by
# its message, once, at import. ``warnings.catch_warnings`` around each matrix, as before, swaps
# the process's filters, from the app's training thread too. The invariant check is declined
# explicitly (``_csr`` builds valid indices), which is what silences torch's second warning.
warnings.filterwarnings(
    "ignore", message="Sparse CSR tensor support is in beta", category=UserWarning
)


def _csr(
    row: torch.Tensor, column: torch.Tensor, value: torch.Tensor, shape: tuple[int, int]
) -> torch.Tensor:
    """A CSR matrix of ``(row, column, value)`` entries in any order, int32 indices."""
    if len(row) > 1 and not bool((row[1:] >= row[:-1]).all()):
        order = torch.argsort(row, stable=True)
        row, column, value = row[order], column[order], value[order]
    return _csr_by_rows(torch.bincount(row.long(), minlength=shape[0]), column, value, shape)


def _merged_rows_by_sorting(
    row: torch.Tensor, texel: torch.Tensor, weight: torch.Tensor, shape: tuple[int, int]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(counts, texel, weight)`` in row order of :meth:`TapMatrix.merged` on any device:
    every tap sorted at once by its (row, texel) key."""
    key = row.long() * shape[1] + texel.long()
    unique, inverse = torch.unique(key, sorted=True, return_inverse=True)
    summed = weight.new_zeros(len(unique)).index_add_(0, inverse, weight)
    merged_row = unique // shape[1]
    counts = torch.bincount(merged_row, minlength=shape[0])
    return counts, (unique - merged_row * shape[1]).int(), summed


def _merged_rows_on_cpu(
    row: torch.Tensor, texel: torch.Tensor, weight: torch.Tensor, shape: tuple[int, int]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(counts, texel, weight)`` in row order of :meth:`TapMatrix.merged` on the CPU: the
    taps counted into their rows, then each row's texels sorted and its taps of one texel
    summed, row by row (the inputs are left as they are)."""
    taps = (weight.numpy(), (row.numpy(), texel.numpy()))
    matrix = scipy.sparse.csr_matrix(taps, shape=shape)  # a copy: duplicates summed
    matrix.sum_duplicates()  # sorted texels in each row (already done where scipy did it)
    counts = torch.from_numpy(np.diff(matrix.indptr).astype(np.int64))
    return counts, torch.from_numpy(matrix.indices).int(), torch.from_numpy(matrix.data)


def _csr_by_rows(
    counts: torch.Tensor, column: torch.Tensor, value: torch.Tensor, shape: tuple[int, int]
) -> torch.Tensor:
    """A CSR matrix of entries in row order, ``counts[r]`` of them in row ``r``."""
    crow = torch.zeros(shape[0] + 1, dtype=torch.int32, device=column.device)
    crow[1:] = torch.cumsum(counts, 0)
    return torch.sparse_csr_tensor(crow, column.int(), value, shape, check_invariants=False)


class _TapProduct(torch.autograd.Function):
    """``taps.matrix @ table``, whose backward is the transpose's product with ``grad``,
    written into the rows of the texels the taps read."""

    @staticmethod
    def forward(ctx, taps: TapMatrix, table: torch.Tensor) -> torch.Tensor:
        ctx.taps = taps
        return taps.matrix @ table

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[None, torch.Tensor]:
        texels, transposed = ctx.taps.transposed
        grad_table = grad.new_zeros(ctx.taps.shape[1], grad.shape[1])
        return None, grad_table.index_add_(0, texels, transposed @ grad.contiguous())


class MipTexture:
    """A texture ready for GPU-style lookups: its mip chain in one flat ``(C, T)`` table.

    Samples are passed as separate ``(N,)`` coordinate vectors and come back as ``(C, N)``:
    one contiguous row per channel keeps the per-sample arithmetic vectorised on the CPU.

    Args:
        texture: ``(H, W, C)`` float linear texture (may require grad).
    """

    def __init__(self, texture: torch.Tensor):
        height, width, self.channels = texture.shape
        self.layout = MipLayout(height, width, texture.device)
        self.size = self.layout.size
        self.num_levels = self.layout.num_levels
        levels = build_mip_chain(texture)
        self.table = torch.cat([level.reshape(-1, self.channels) for level in levels])

    @cached_property
    def texels(self) -> torch.Tensor:
        """``(C, T)`` the chain's texels of all levels, one contiguous row per channel."""
        return self.table.T.contiguous()

    def bilinear(self, u: torch.Tensor, v: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """``(C, N)`` bilinear samples at integer mip ``level`` (see :class:`MipLayout`)."""
        return gather(self.texels, *self.layout.bilinear_taps(u, v, level))

    def level_of_detail(self, *derivatives: torch.Tensor) -> torch.Tensor:
        """``(N,)`` level of detail, :meth:`MipLayout.level_of_detail`."""
        return self.layout.level_of_detail(*derivatives)

    def trilinear(self, u: torch.Tensor, v: torch.Tensor, lod: torch.Tensor) -> torch.Tensor:
        """``(C, N)`` trilinear samples at level of detail ``lod`` (clamped to the chain).

        The same sum as gathering :meth:`MipLayout.trilinear_taps`, evaluated as a blend of
        two bilinear lookups. Where texels are magnified (``lod < 0``) the coarser level has
        weight 0 and is not looked up: on a typical view that is most samples.
        """
        fine, coarse, blend = self.layout.levels(lod)
        colour = self.bilinear(u, v, fine)
        blended = torch.nonzero(lod >= 0).squeeze(1)
        if len(blended) == 0:
            return colour
        u, v, coarse, blend = (t.index_select(0, blended) for t in (u, v, coarse, blend))
        mixed = torch.lerp(colour.index_select(1, blended), self.bilinear(u, v, coarse), blend)
        return colour.index_copy(1, blended, mixed)

    def sample(self, footprint: UVFootprint) -> torch.Tensor:
        """GPU-style texture lookup of every sample of a footprint: ``(C, N)``."""
        lod = self.layout.level_of_detail(
            footprint.du_dx, footprint.dv_dx, footprint.du_dy, footprint.dv_dy
        )
        return self.trilinear(footprint.u, footprint.v, lod)


def fill_gutters(texture: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """Pull-push fill: texels outside ``keep`` take the average colour of the nearest kept ones.

    Kept texels are returned unchanged. Pull: average colour and coverage down a pyramid of
    2 x 2 sums; push: every other texel takes the value of its parent one level coarser.

    Args:
        texture: ``(h, w, C)`` float texture.
        keep: ``(h, w)`` bool.

    Returns:
        ``(h, w, C)`` texture with every texel defined (if any texel is kept).
    """
    if keep.all() or not keep.any():
        return texture.clone()
    weight = keep.to(texture.dtype)[None, None]
    value = texture.permute(2, 0, 1)[None] * weight
    pyramid = [(value, weight)]
    while pyramid[-1][1].shape[-1] > 1 or pyramid[-1][1].shape[-2] > 1:
        value, weight = pyramid[-1]
        pool = lambda x: F.avg_pool2d(x, 2, ceil_mode=True) * 4  # noqa: E731
        pyramid.append((pool(value), pool(weight)))
    value, weight = pyramid[-1]
    filled = value / weight.clamp_min(1e-12)
    for value, weight in reversed(pyramid[:-1]):
        parent = F.interpolate(filled, scale_factor=2, mode="nearest")
        parent = parent[..., : value.shape[-2], : value.shape[-1]]
        own = value / weight.clamp_min(1e-12)
        filled = torch.where(weight > 0, own, parent)
    result = filled[0].permute(1, 2, 0)
    return torch.where(keep[..., None], texture, result)
