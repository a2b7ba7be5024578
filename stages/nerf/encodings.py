"""Spatial encodings of the NeRF field: TensoRF VM grid, multiresolution hash grid, sinusoids.

All take grid coordinates in [-1, 1]^3 (the scene box, see `scene.py`). The grid encodings share
one interpolation kernel, `gather_interp`: a weighted sum of K table rows per point. Its forward is
`F.embedding_bag` (rows are channels-last, so one point reads contiguous memory) and its backward
an accumulating scatter into the table's gradient (a compiled loop on a CPU, grid_kernels.py):
the sample positions never need gradients here (normals come from finite differences), which keeps
both passes cheap on a CPU.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from endopipe.stages.nerf.grid_kernels import VM_PAIRS, add_weighted_corners, reads_fused, vm_read


class _GatherInterp(torch.autograd.Function):
    @staticmethod
    def forward(ctx, table: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        n, k = idx.shape
        offsets = torch.arange(0, n * k, k, device=idx.device)
        out = F.embedding_bag(
            idx.reshape(-1), table, offsets, mode="sum", per_sample_weights=w.reshape(-1)
        )
        ctx.save_for_backward(idx, w)
        ctx.table = table
        return out

    @staticmethod
    def backward(ctx, grad: torch.Tensor):  # type: ignore[override]
        idx, w = ctx.saved_tensors
        table: torch.Tensor = ctx.table
        grad = grad.contiguous()
        # A table is a leaf parameter read several times a step (the fine pass, normals, the
        # SfM-point and neighbour rays): every read scatters into its one .grad instead of a
        # dense gradient of its own that autograd then adds up (at 384 nodes, allocating and
        # adding those cost a tenth of a step).
        direct = table.is_leaf and table.requires_grad
        if direct:
            if table.grad is None:
                table.grad = _zeroed_buffer(table)
            g = table.grad
        else:
            g = torch.zeros_like(table, dtype=grad.dtype)
        if g.device.type == "cpu" and g.is_contiguous():
            add_weighted_corners(g, idx, w, grad)  # no sort (grid_kernels.py)
        else:  # one corner at a time: contiguous products, no (N, K, C) temporary
            for k in range(idx.shape[1]):
                g.index_add_(0, idx[:, k], grad * w[:, k : k + 1])
        return (None if direct else g), None, None


def _zeroed_buffer(table: torch.Tensor) -> torch.Tensor:
    """The table's gradient buffer, zeroed: kept across steps, since on a CPU a fresh tensor
    the size of a 384-node plane costs ten times a zeroing (its pages are faulted in anew)."""
    buf: torch.Tensor | None = getattr(table, "_grad_buffer", None)
    if buf is None or buf.shape != table.shape or buf.dtype != table.dtype:
        buf = torch.zeros_like(table)
        table._grad_buffer = buf  # type: ignore[attr-defined]
    else:
        buf.zero_()
    return buf


def gather_interp(table: torch.Tensor, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """sum_k w[n, k] * table[idx[n, k]] -> (N, C); gradients flow to `table` only."""
    return _GatherInterp.apply(table, idx, w.detach().to(table.dtype))


class VMGrid(nn.Module):
    """TensoRF's vector-matrix factorisation: sum_m plane_m(u, v) * line_m(w), R channels.

    Three plane/line pairs: (xy | z), (xz | y), (yz | x). `forward` returns the products per
    point, shape (N, 3 R) ordered pair-major; density sums them, appearance uses them as they
    are. Grids of the same resolution can share the interpolation set-up (`prepare`).
    """

    PAIRS = VM_PAIRS

    def __init__(self, res: tuple[int, int, int], channels: int, init_std: float = 0.1) -> None:
        super().__init__()
        self.channels = channels
        self.res = tuple(int(r) for r in res)
        g = torch.Generator().manual_seed(0)
        self.planes = nn.Parameter(
            init_std * torch.randn(self._plane_rows(), channels, generator=g)
        )
        self.lines = nn.Parameter(init_std * torch.randn(self._line_rows(), channels, generator=g))
        self._consts: dict[str, tuple[torch.Tensor, ...]] = {}

    def _plane_rows(self) -> int:
        return sum(self.res[a] * self.res[b] for a, b, _ in self.PAIRS)

    def _line_rows(self) -> int:
        return sum(self.res[c] for *_, c in self.PAIRS)

    def _constants(self, device: torch.device) -> tuple[torch.Tensor, ...]:
        key = str(device)
        if key not in self._consts:
            a = torch.tensor([p[0] for p in self.PAIRS], device=device)
            b = torch.tensor([p[1] for p in self.PAIRS], device=device)
            c = torch.tensor([p[2] for p in self.PAIRS], device=device)
            res = torch.tensor(self.res, device=device)
            ra = res[a]
            sizes = res[a] * res[b]
            poff = torch.cumsum(sizes, 0) - sizes
            loff = torch.cumsum(res[c], 0) - res[c]
            corner = torch.stack([torch.zeros_like(ra), torch.ones_like(ra), ra, ra + 1], -1)
            self._consts[key] = (a, b, c, res, ra, poff, loff, corner)
        return self._consts[key]

    def prepare(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Interpolation indices and weights of points x (N, 3) in [-1, 1]^3."""
        a, b, c, res, ra, poff, loff, corner = self._constants(x.device)
        with torch.no_grad():
            p = ((x + 1.0) * (0.5 * (res - 1))).clamp_(min=0.0).minimum(res - 1.0)
            i = p.floor().minimum(res - 2.0)
            f = p - i
            i = i.long()
            fa, fb, fc = f[:, a], f[:, b], f[:, c]
            base = poff + i[:, b] * ra + i[:, a]  # (N, 3)
            pidx = (base[..., None] + corner).reshape(-1, 4)
            ga, gb = 1.0 - fa, 1.0 - fb
            pw = torch.stack([ga * gb, fa * gb, ga * fb, fa * fb], -1).reshape(-1, 4)
            lbase = loff + i[:, c]
            lidx = torch.stack([lbase, lbase + 1], -1).reshape(-1, 2)
            lw = torch.stack([1.0 - fc, fc], -1).reshape(-1, 2)
        return pidx, pw, lidx, lw

    @staticmethod
    def select(prep: tuple, keep: torch.Tensor, n: int) -> tuple:
        """The set-up of `prepare` for the points `keep` (indices) of its `n` points: rows of
        three (one a plane / line pair) per point; anything else (a time) as it is."""
        out = []
        for a in prep:
            if a is not None and a.dim() == 2 and a.shape[0] == 3 * n:
                a = a.view(n, 3, -1)[keep].reshape(-1, a.shape[1])
            out.append(a)
        return tuple(out)

    def reads_fused(self, x: torch.Tensor) -> bool:
        """Whether a read of x needs no set-up (no gradient wanted: grid_kernels.py)."""
        return reads_fused(x, *self.parameters())

    def forward(
        self, x: torch.Tensor, prep: tuple[torch.Tensor, ...] | None = None
    ) -> torch.Tensor:
        if prep is None and self.reads_fused(x):
            _, _, _, res, _, poff, loff, _ = self._constants(x.device)
            return vm_read(x, self.planes, self.lines, res, poff, loff)
        pidx, pw, lidx, lw = prep if prep is not None else self.prepare(x)
        plane = gather_interp(self.planes, pidx, pw)
        line = gather_interp(self.lines, lidx, lw)
        return (plane * line).view(x.shape[0], 3 * self.channels)

    @torch.no_grad()
    def upsampled(self, res: tuple[int, int, int]) -> VMGrid:
        """A copy at another resolution (bilinear / linear resampling, align_corners)."""
        new = VMGrid(res, self.channels)
        planes, lines = [], []
        poff, loff = 0, 0
        for a, b, c in self.PAIRS:
            ra, rb, rc = self.res[a], self.res[b], self.res[c]
            p = self.planes[poff : poff + ra * rb].T.reshape(1, self.channels, rb, ra)
            p = F.interpolate(p, size=(res[b], res[a]), mode="bilinear", align_corners=True)
            planes.append(p.reshape(self.channels, -1).T)
            ln = self.lines[loff : loff + rc].T.reshape(1, self.channels, rc)
            ln = F.interpolate(ln, size=(res[c],), mode="linear", align_corners=True)
            lines.append(ln.reshape(self.channels, -1).T)
            poff += ra * rb
            loff += rc
        new.planes = nn.Parameter(torch.cat(planes).contiguous())
        new.lines = nn.Parameter(torch.cat(lines).contiguous())
        return new.to(self.planes.device)

    def total_variation(self) -> torch.Tensor:
        """Mean squared difference of neighbouring plane and line entries (TensoRF's TV)."""
        tv = self.planes.new_zeros(())
        poff, loff = 0, 0
        for a, b, c in self.PAIRS:
            ra, rb, rc = self.res[a], self.res[b], self.res[c]
            p = self.planes[poff : poff + ra * rb].view(rb, ra, -1)
            tv = tv + (p[1:] - p[:-1]).square().mean() + (p[:, 1:] - p[:, :-1]).square().mean()
            ln = self.lines[loff : loff + rc]
            tv = tv + (ln[1:] - ln[:-1]).square().mean()
            poff += ra * rb
            loff += rc
        return tv


#: A grid over time reads points at up to this many times in one compiled pass (their lines
#: sliced at each: at 384 nodes and 32 channels, 64 slices are 9 MB).
FUSED_TIMES = 64


def point_times(t: torch.Tensor, most: int) -> tuple[torch.Tensor, torch.Tensor | None] | None:
    """The distinct times of points at times `t` (N,) and each point's among them (None: all
    at one), for reading a grid over time's lines sliced at each; None: no points, or more
    than `most` times."""
    if len(t) == 0:
        return None
    if bool((t == t[0]).all()):
        return t[:1], None
    if most < 2:
        return None
    times, which = torch.unique(t, return_inverse=True)
    return (times, which) if len(times) <= most else None


class VMTimeGrid(VMGrid):
    """HexPlane's space-time factorisation on the VM grid, as a static grid and a change:
    sum_m plane_m(u, v) * (line_m(w) + change_m(w, t)), the change a plane over (w, time) with
    `times` nodes along time, zero at the start.

    Why this form: a scene that deforms is still mostly the same scene. The static planes and
    lines learn from every ray, as the static grid's do; the change, fitted by the few rays of
    each time, carries only what the frames differ by, and `change_penalty` keeps it small and
    smooth in time. Lines grown into (w, t) planes with no static part (plain HexPlane) stalled
    on a still da Vinci clip: each time node saw 1/times of the rays and wandered (held-out
    18.9 dB against the static field's 20.7). Points are (N, 4): grid x, y, z and the time, all
    in [-1, 1]. Upsampling refines space only (the time nodes are fixed).
    """

    #: Points at up to this many distinct times read the lines sliced at each of them: a
    #: batch drawn from a few frames (`nerf.train.frames_per_step`) sets it; 1: only points all
    #: at one time (a frame rendered at its own).
    slice_up_to: int = 1

    def __init__(
        self, res: tuple[int, int, int], channels: int, times: int, init_std: float = 0.1
    ) -> None:
        super().__init__(res, channels, init_std)
        self.times = int(times)
        self.change = nn.Parameter(torch.zeros(self.times * self._line_rows(), channels))

    def prepare(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """As VMGrid's, and where the change is read. Points at no more than `slice_up_to`
        distinct times read the lines sliced at those times (`sliced`): `cidx` is None, `cw`
        the times and `lidx` points into the slice of each point's time. Otherwise the
        change's (w, time) corners and weights. (Slicing at each of a training batch's
        frames, 136 times, made a step slower: 221 ms against 194, three runs of 60 steps each
        on the cutting clip, scripts/bench_nerf_step.py; the slice's backward grows with its
        times.)"""
        pidx, pw, lidx, lw = super().prepare(x[:, :3])
        at = point_times(x[:, 3], self.slice_up_to)
        if at is not None:
            times, which = at
            if which is not None:
                shift = which.repeat_interleave(len(self.PAIRS)) * self._line_rows()
                lidx = lidx + shift[:, None]
            return pidx, pw, lidx, lw, None, times
        _, _, c, res, _, _, loff, _ = self._constants(x.device)
        with torch.no_grad():
            p = ((x[:, :3] + 1.0) * (0.5 * (res - 1))).clamp_(min=0.0).minimum(res - 1.0)
            ic = p[:, c].floor().minimum(res[c] - 2.0)
            fc = p[:, c] - ic
            q = ((x[:, 3] + 1.0) * (0.5 * (self.times - 1))).clamp_(0.0, self.times - 1.0)
            it = q.floor().clamp_(max=max(self.times - 2, 0))
            ft = (q - it)[:, None]
            rc = res[c]
            base = self.times * loff + it.long()[:, None] * rc + ic.long()  # (N, 3)
            step = rc if self.times > 1 else torch.zeros_like(rc)
            cidx = torch.stack([base, base + 1, base + step, base + step + 1], -1).reshape(-1, 4)
            gc, gt = 1.0 - fc, 1.0 - ft
            cw = torch.stack([gc * gt, fc * gt, gc * ft, fc * ft], -1).reshape(-1, 4)
        return pidx, pw, lidx, lw, cidx, cw

    def forward(
        self, x: torch.Tensor, prep: tuple[torch.Tensor, ...] | None = None
    ) -> torch.Tensor:
        if prep is None and self.reads_fused(x):
            out = self._read_sliced(x)
            if out is not None:
                return out
        pidx, pw, lidx, lw, cidx, cw = prep if prep is not None else self.prepare(x)
        plane = gather_interp(self.planes, pidx, pw)
        if cidx is None:  # the lines at the times `cw` (the same sums, a third less time)
            line = gather_interp(self.sliced(cw), lidx, lw)
        else:
            line = gather_interp(self.lines, lidx, lw) + gather_interp(self.change, cidx, cw)
        return (plane * line).view(x.shape[0], 3 * self.channels)

    def _read_sliced(self, x: torch.Tensor) -> torch.Tensor | None:
        """A read that wants no gradient (a frame rendered at its time, a training step's first
        pass at its frames' times): the lines sliced at the points' times, then one compiled
        pass that reads each point's slice (the same sums as the gathers'). None: no points, or
        points at more than FUSED_TIMES times (the slices would outgrow the read)."""
        at = point_times(x[:, 3], FUSED_TIMES)
        if at is None:
            return None
        times, which = at
        shift = None if which is None else which * self._line_rows()
        _, _, _, res, _, poff, loff, _ = self._constants(x.device)
        return vm_read(x[:, :3], self.planes, self.sliced(times), res, poff, loff, shift)

    def sliced(self, times: torch.Tensor) -> torch.Tensor:
        """The lines plus the change at each of `times` (U,) in [-1, 1], the change linear
        between its time nodes as `prepare` weighs it: (U x line rows, channels), time-major
        (row u x line rows + r: line row r at time u)."""
        q = ((times + 1.0) * (0.5 * (self.times - 1))).clamp(0.0, self.times - 1.0)
        it = q.floor().clamp(max=max(self.times - 2, 0))
        ft = (q - it).to(self.change.dtype)[:, None, None]
        it = it.long()
        nxt = (it + 1).clamp(max=self.times - 1)
        parts, off = [], 0
        for *_, c in self.PAIRS:
            rc = self.res[c]
            ch = self.change[off : off + self.times * rc].view(self.times, rc, -1)
            parts.append((1.0 - ft) * ch[it] + ft * ch[nxt])
            off += self.times * rc
        return (self.lines[None] + torch.cat(parts, 1)).reshape(-1, self.channels)

    @torch.no_grad()
    def upsampled(self, res: tuple[int, int, int]) -> VMTimeGrid:
        space = VMGrid.upsampled(self, res)
        new = VMTimeGrid(res, self.channels, self.times)
        new.slice_up_to = self.slice_up_to
        new.planes, new.lines = space.planes, space.lines
        change, off = [], 0
        for *_, c in self.PAIRS:
            rc = self.res[c]
            ch = self.change[off : off + self.times * rc].T.reshape(
                1, self.channels, self.times, rc
            )
            ch = F.interpolate(ch, size=(self.times, res[c]), mode="bilinear", align_corners=True)
            change.append(ch.reshape(self.channels, -1).T)
            off += self.times * rc
        new.change = nn.Parameter(torch.cat(change).contiguous())
        return new.to(self.planes.device)

    def change_penalty(self) -> torch.Tensor:
        """Mean square of the change's steps between time nodes: the scene changes slowly.
        (Its size is not penalised: a penalty of 0.01 on its mean square kept a tint that
        changes over the clip out of the field.)"""
        total = self.change.new_zeros(())
        off = 0
        for *_, c in self.PAIRS:
            rc = self.res[c]
            ch = self.change[off : off + self.times * rc].view(self.times, rc, -1)
            if self.times > 1:
                total = total + (ch[1:] - ch[:-1]).square().mean()
            off += self.times * rc
        return total


_PRIMES = (1, 2654435761, 805459861)


class HashGrid(nn.Module):
    """Instant-NGP multiresolution hash encoding in plain PyTorch (levels x features out).

    Coarse levels that fit in the table are indexed densely; finer ones through the spatial hash.
    """

    def __init__(
        self,
        levels: int = 16,
        features: int = 2,
        log2_size: int = 19,
        base_res: int = 16,
        max_res: int = 1024,
    ) -> None:
        super().__init__()
        self.levels, self.features = levels, features
        self.size = 2**log2_size
        growth = math.exp((math.log(max_res) - math.log(base_res)) / max(levels - 1, 1))
        self.res = [int(math.floor(base_res * growth**lv)) for lv in range(levels)]
        rows, self.offsets, self.dense = 0, [], []
        for r in self.res:
            n = (r + 1) ** 3
            dense = n <= self.size
            self.dense.append(dense)
            self.offsets.append(rows)
            rows += n if dense else self.size
        g = torch.Generator().manual_seed(0)
        self.table = nn.Parameter((torch.rand(rows, features, generator=g) * 2 - 1) * 1e-4)
        corners = torch.tensor([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        self.register_buffer("corners", corners, persistent=False)

    @property
    def out_dim(self) -> int:
        return self.levels * self.features

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n = x.shape[0]
        with torch.no_grad():
            u = ((x + 1.0) * 0.5).clamp(0.0, 1.0)
            idx_all, w_all = [], []
            for lv, r in enumerate(self.res):
                p = u * r
                i0 = p.floor().clamp(max=r - 1)
                f = p - i0
                c = i0.long().unsqueeze(1) + self.corners  # (N, 8, 3)
                wc = torch.where(self.corners.bool(), f.unsqueeze(1), 1.0 - f.unsqueeze(1))
                w = wc.prod(-1)
                if self.dense[lv]:
                    idx = (c[..., 0] * (r + 1) + c[..., 1]) * (r + 1) + c[..., 2]
                else:
                    h = c[..., 0] * _PRIMES[0]
                    h = torch.bitwise_xor(h, c[..., 1] * _PRIMES[1])
                    h = torch.bitwise_xor(h, c[..., 2] * _PRIMES[2])
                    idx = h % self.size
                idx_all.append(idx + self.offsets[lv])
                w_all.append(w)
            idx = torch.stack(idx_all, 1).reshape(n * self.levels, 8)
            w = torch.stack(w_all, 1).reshape(n * self.levels, 8)
        return gather_interp(self.table, idx, w).view(n, self.out_dim)


def sinusoidal(x: torch.Tensor, bands: int, include_input: bool = True) -> torch.Tensor:
    """NeRF positional encoding: [x, sin(2^k pi x), cos(2^k pi x)] for k < bands."""
    if bands <= 0:
        return x
    freqs = (2.0 ** torch.arange(bands, device=x.device, dtype=x.dtype)) * math.pi
    xb = (x.unsqueeze(-1) * freqs).flatten(-2)
    out = [torch.sin(xb), torch.cos(xb)]
    return torch.cat(([x] if include_input else []) + out, -1)


def sinusoidal_dim(dims: int, bands: int, include_input: bool = True) -> int:
    return dims * (2 * bands + (1 if include_input else 0)) if bands > 0 else dims
