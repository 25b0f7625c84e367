"""The global search: templates of the walls for every rotation and both mirrors, a
rotation-invariant detector correlated with the shrunk orientation field of every scale by one
circular cross-correlation (DFT) of a mosaic, and the proposals it yields."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from tympani.vision.geometry import CameraPose
from tympani.vision.registration.config import RegistrationConfig
from tympani.vision.registration.frames import Edges
from tympani.vision.registration.model import WallModel
from tympani.vision.registration.poses import image_points, wrap


@dataclass(frozen=True)
class Proposal:
    """A candidate pose and its score (larger is better; units depend on the stage)."""

    score: float
    pose: CameraPose


def _splat_many(
    points: np.ndarray, values: np.ndarray, which: np.ndarray, n_images: int, shape: tuple[int, int]
) -> np.ndarray:
    """Bilinear splat of complex ``values`` at ``points`` (px) into image ``which`` of a stack.

    Points are clipped to the image (callers keep them inside). Returns an
    ``(n_images, h * w)`` complex array.
    """
    h, w = shape
    x = np.clip(points[:, 0], 0.0, w - 1.0001)
    y = np.clip(points[:, 1], 0.0, h - 1.0001)
    x0, y0 = x.astype(np.intp), y.astype(np.intp)
    fx, fy = x - x0, y - y0
    base = which * (h * w) + y0 * w + x0
    idx = np.concatenate([base, base + 1, base + w, base + w + 1])
    wgt = np.concatenate([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
    vals = np.tile(values, 4) * wgt
    n = n_images * h * w
    out = np.empty(n, np.complex128)
    out.real = np.bincount(idx, vals.real, minlength=n)
    out.imag = np.bincount(idx, vals.imag, minlength=n)
    return out.reshape(n_images, h * w)


@dataclass(frozen=True)
class _TemplateStack:
    """Coarse templates of the walls for every rotation and both mirrors.

    Each template is a ``size x size`` doubled-angle image of the walls at
    ``coarse_px_per_mm`` with the spiral centre on its middle pixel.
    """

    size: int
    rotations: np.ndarray  # (J,) rotation_rad of each template
    # (K, 2J) float32, mirror-major columns: the rows of [real parts; imaginary parts] (2 size²
    # of them) on which some template is non-zero (K is about 70 % of them; the others would
    # only add zeros to the scores)
    stack_real: np.ndarray
    patch_index: np.ndarray  # (K,) where those rows are in a (size, size, 2) patch, flattened
    mean: np.ndarray  # (2, size, size, 2) float32: rotation-averaged template of each mirror
    # memo of the search's per-image-size work, filled by _coarse_plan (read-only values):
    # field shapes -> (block offsets, DFT size, _pair_spectra of ``mean``'s spectra at that size)
    plans: dict = field(default_factory=dict, compare=False, repr=False)


def _template_stack(model: WallModel, cfg: RegistrationConfig) -> _TemplateStack:
    """Render the two mirrors' templates once and rotate them with ``cv2.warpAffine``.

    Raising ``rotation_rad`` by phi turns the image by ``R(-phi)`` about the centre and
    multiplies the doubled-angle values by ``exp(-2i phi)``.
    """
    w0 = cfg.coarse_px_per_mm
    radius = float(np.max(np.hypot(model.points[:, 0], model.points[:, 1])))
    size = 2 * int(math.ceil(radius * w0 + 2.5)) + 1
    c = float(size // 2)
    coarse = model.subsample(0.25 / w0)
    weight = coarse.spacing_mm * w0  # template density: 1 per coarse px of wall
    rotations = np.arange(cfg.coarse_rotations) * (2 * np.pi / cfg.coarse_rotations)
    bases = []
    for mirrored in (False, True):
        pts, nrm = image_points(CameraPose(c, c, 0.0, w0, mirrored), coarse)
        val = weight * (nrm[:, 0] + 1j * nrm[:, 1]) ** 2
        flat = _splat_many(pts, val, np.zeros(len(pts), np.intp), 1, (size, size))[0].reshape(size, size)
        bases.append(np.dstack([flat.real, flat.imag]).astype(np.float32))
    images = np.empty((2, len(rotations), size, size, 2), np.float32)
    for m, base in enumerate(bases):
        for j, phi in enumerate(rotations):
            cs, sn = math.cos(phi), math.sin(phi)
            # destination x samples the base at c + R(phi) (x - c)
            rot = np.array([[cs, -sn, c - cs * c + sn * c], [sn, cs, c - sn * c - cs * c]], np.float64)
            images[m, j] = cv2.warpAffine(
                base, rot, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=0.0
            )
    phase_c = np.cos(2 * rotations).astype(np.float32)[None, :, None, None]  # exp(-2i phi)
    phase_s = -np.sin(2 * rotations).astype(np.float32)[None, :, None, None]
    re, im = images[..., 0].copy(), images[..., 1]
    images[..., 0] = re * phase_c - im * phase_s
    images[..., 1] = re * phase_s + im * phase_c
    flat = images.reshape(2 * len(rotations), size * size, 2)
    stack_real = np.hstack([flat[..., 0], flat[..., 1]]).T
    support = np.flatnonzero(np.any(stack_real != 0, axis=1))  # row = channel * size² + pixel
    patch_index = (support % (size * size)) * 2 + support // (size * size)
    mean = np.ascontiguousarray(images.mean(axis=1))
    return _TemplateStack(size, rotations, np.ascontiguousarray(stack_real[support]), patch_index, mean)


_TEMPLATE_CACHE: dict[tuple, _TemplateStack] = {}


def _cached_template_stack(model: WallModel, cfg: RegistrationConfig) -> _TemplateStack:
    """:func:`_template_stack`, kept for the last walls and settings it was built for: every
    registration in a process (each video of a batch, a re-registration) of the same phantom
    reuses it (~35 ms each). The key holds the walls' bytes, so equal walls hit."""
    key = (model.points.tobytes(), model.normals.tobytes(), model.spacing_mm, cfg.coarse_px_per_mm,
           cfg.coarse_rotations)
    tpl = _TEMPLATE_CACHE.get(key)
    if tpl is None:
        tpl = _template_stack(model, cfg)
        for a in (tpl.rotations, tpl.stack_real, tpl.patch_index, tpl.mean):
            a.flags.writeable = False
        _TEMPLATE_CACHE.clear()
        _TEMPLATE_CACHE[key] = tpl
    return tpl


def _peaks(score: np.ndarray, n: int, radius: int) -> list[tuple[int, int]]:
    """Up to ``n`` local maxima (row, col) of ``score``, at least ``radius`` apart."""
    k = 2 * radius + 1
    score = np.asarray(score, dtype=np.float32)  # a view with padded rows is fine
    dil = cv2.dilate(score, np.ones((k, k), np.uint8))
    flat = np.flatnonzero(score >= dil)  # row-major order, as np.argwhere
    values = dil.reshape(-1)[flat]  # = the score there (a local maximum is its own dilation)
    flat, values = flat[values > 0], values[values > 0]  # the positive ones (few: no full-size test)
    if len(flat) == 0:
        return []
    width = score.shape[1]
    out: list[tuple[int, int]] = []
    for i in np.argsort(-values).tolist():
        r, c = divmod(int(flat[i]), width)
        if all(max(abs(r - r2), abs(c - c2)) > radius for r2, c2 in out):
            out.append((r, c))
            if len(out) == n:
                break
    return out


def _shrunk_field(pyramid: list[np.ndarray], factor: float) -> tuple[np.ndarray, float, float]:
    """The doubled-angle field shrunk by ``factor`` (> 1), as edge length per shrunk pixel.

    Starts from the pyramid level that leaves at least a factor 2 to shrink. Returns the
    2-channel float32 image and the actual x and y shrink factors (full-resolution px per
    shrunk px).
    """
    level = min(max(math.floor(math.log2(max(factor, 1.0) / 2.0)), 0), len(pyramid) - 1)
    src = pyramid[level]
    h0, w0 = pyramid[0].shape[:2]
    h, w = src.shape[:2]
    wk = max(1, int(round(w0 / factor)))
    hk = max(1, int(round(h0 / factor)))
    zk = cv2.resize(src, (wk, hk), interpolation=cv2.INTER_AREA).reshape(hk, wk, 2)
    zk *= math.sqrt((w / wk) * (h / hk))
    zk = cv2.GaussianBlur(zk, (0, 0), 0.8).reshape(hk, wk, 2)
    return zk, w0 / wk, h0 / hk


def _shelf_layout(shapes: list[tuple[int, int]], gap: int, width: int) -> tuple[list[tuple[int, int]], tuple[int, int]]:
    """Blocks of ``shapes`` ((rows, cols), px) packed in order on shelves ``width`` px wide.

    A block starts a new shelf when it would end beyond ``width`` (a block wider than that
    gets a shelf of its own). Every block has ``gap`` px of empty space before it in both
    directions (to the previous block, the previous shelf or the mosaic's start). Returns
    the (row, col) of each block's first pixel and the (rows, cols) of the packed area (up
    to the last block's end, no trailing gap).
    """
    offsets = []
    x, y, shelf, right = gap, gap, 0, 0
    for h, w in shapes:
        if x > gap and x + w > width:
            x, y, shelf = gap, y + shelf + gap, 0
        offsets.append((y, x))
        right = max(right, x + w)
        shelf = max(shelf, h)
        x += w + gap
    return offsets, (y + shelf, right)


def _mosaic_layout(shapes: list[tuple[int, int]], gap: int) -> tuple[list[tuple[int, int]], tuple[int, int]]:
    """Shelf layout of ``shapes`` (see :func:`_shelf_layout`) whose DFT is cheapest.

    Tries shelf widths in 32 px steps from the widest block (plus ``gap``) to about twice
    the square root of the packed area and keeps the one with the smallest DFT
    (``cv2.getOptimalDFTSize`` of each side).
    Returns the blocks' (row, col) offsets and the DFT size (rows, cols), which covers the
    packed area.
    """
    widest = max(w for _, w in shapes) + gap
    area = sum((h + gap) * (w + gap) for h, w in shapes)
    best: tuple[int, list[tuple[int, int]], tuple[int, int]] | None = None
    for width in range(widest, max(widest, int(2.0 * math.sqrt(area))) + 1, 32):
        offsets, (rows, cols) = _shelf_layout(shapes, gap, width)
        size = (cv2.getOptimalDFTSize(rows), cv2.getOptimalDFTSize(cols))
        if best is None or size[0] * size[1] < best[0]:
            best = (size[0] * size[1], offsets, size)
    assert best is not None
    return best[1], best[2]


def _template_spectra(templates: np.ndarray, rows: int, cols: int) -> list[np.ndarray]:
    """DFTs of ``templates`` zero-padded to ``rows x cols`` (px).

    Parameters
    ----------
    templates : ndarray of float32, shape (n, s, s, 2)
        Complex templates (real, imaginary), at most ``rows x cols``.
    rows, cols : int
        DFT size (px).

    Returns
    -------
    list of ndarray of complex64, shape (rows, cols)
        One spectrum per template.
    """
    padded = np.zeros((rows, cols, 2), np.float32)
    spectra = []
    for t in templates:
        padded[: t.shape[0], : t.shape[1]] = t
        spectra.append(cv2.dft(padded, flags=cv2.DFT_COMPLEX_OUTPUT).view(np.complex64)[..., 0])
    return spectra


def _reversed_conj(spectrum: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out[k] = conj(spectrum[-k])`` for a 2-D spectrum (indices modulo its size, both axes)."""
    np.conjugate(spectrum[0, 0], out=out[0, 0:1])
    np.conjugate(spectrum[0, :0:-1], out=out[0, 1:])
    np.conjugate(spectrum[:0:-1, 0], out=out[1:, 0])
    np.conjugate(spectrum[:0:-1, :0:-1], out=out[1:, 1:])
    return out


def _pair_spectra(t0: np.ndarray, t1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The factors ``A``, ``B`` with which :func:`_circular_ccorr_pair` correlates an image
    with two templates of spectra ``t0``, ``t1`` (complex64, (H, W)) by one inverse DFT.

    With ``Z`` the image's spectrum, template m's circular cross-correlation is
    ``IDFT(Z conj(T_m))`` and its real part the IDFT of the Hermitian part
    ``(P(k) + conj(P(-k))) / 2`` of ``P = Z conj(T_m)``. The two real parts are therefore the
    real and imaginary parts of the IDFT of ``Z(k) A(k) + conj(Z(-k)) B(k)``, with
    ``A = (conj(T_0) + i conj(T_1)) / 2`` and ``B(k) = (T_0(-k) + i T_1(-k)) / 2``.
    """
    t0, t1 = t0.astype(np.complex128), t1.astype(np.complex128)
    a = 0.5 * (np.conj(t0) + 1j * np.conj(t1))
    # conj(C(-k)) with C = conj(T_0 + i T_1) / 2 is (T_0(-k) + i T_1(-k)) / 2
    b = _reversed_conj(0.5 * np.conj(t0 + 1j * t1), np.empty_like(a))
    return a.astype(np.complex64), b.astype(np.complex64)


def _circular_ccorr_pair(image: np.ndarray, factors: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Larger of two templates' circular cross-correlations with ``image`` (by DFT).

    ``out[u, v] = max_m sum Re(image[(u + i) mod H, (v + j) mod W] · conj(t_m[i, j]))``, the
    sum running over the template's pixels and the two channels being the real and imaginary
    parts; where a template placed at ``(u, v)`` does not wrap, this is ``cv2.matchTemplate``
    with ``TM_CCORR`` (up to float rounding). Both templates take one forward and one
    inverse DFT of the image's size (:func:`_pair_spectra`).

    Parameters
    ----------
    image : ndarray of float32, shape (H, W, 2)
        Complex image (real, imaginary), C-contiguous; overwritten (its memory holds the
        spectrum: every new array of this size costs more in page faults than its arithmetic).
    factors : tuple of ndarray of complex64, shape (H, W)
        :func:`_pair_spectra` of the templates' spectra at the image's size.

    Returns
    -------
    ndarray of float32, shape (H, W)
    """
    a, b = factors
    cv2.dft(image, dst=image, flags=cv2.DFT_COMPLEX_OUTPUT)
    z = image.view(np.complex64)[..., 0]
    mirrored = _reversed_conj(z, np.empty_like(z))
    mirrored *= b
    z *= a
    z += mirrored
    cv2.dft(image, dst=image, flags=cv2.DFT_INVERSE | cv2.DFT_SCALE)
    return np.maximum(image[..., 0], image[..., 1])


def _coarse_plan(
    tpl: _TemplateStack, shapes: list[tuple[int, int]]
) -> tuple[list[tuple[int, int]], tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """Mosaic layout (:func:`_mosaic_layout`, gap a template size) of fields of ``shapes``
    ((rows, cols), px) and the spectra of the two mirrors' rotation-averaged templates at its
    DFT size, as :func:`_pair_spectra`.

    Both depend only on the image size and the settings, so they are memoised on ``tpl``
    (every video of a batch has the same size); the spectra are read-only.
    """
    key = tuple(shapes)
    plan = tpl.plans.get(key)
    if plan is None:
        offsets, (rows, cols) = _mosaic_layout(list(shapes), gap=tpl.size)
        spectra = _pair_spectra(*_template_spectra(tpl.mean, rows, cols))
        for a in spectra:
            a.flags.writeable = False
        if len(tpl.plans) >= 4:
            tpl.plans.clear()
        plan = tpl.plans[key] = (offsets, (rows, cols), spectra)
    return plan


def _copy_window(out: np.ndarray, image: np.ndarray, top: int, left: int) -> None:
    """Copy ``image[top : top + rows, left : left + cols]`` (px; ``(rows, cols)`` the shape of
    ``out``) into ``out`` where the window overlaps ``image``; the rest of ``out`` is left
    as it is (zeros, for a window of ``image`` padded with zeros on every side)."""
    rows, cols = out.shape[:2]
    h, w = image.shape[:2]
    r0, r1 = max(top, 0), min(top + rows, h)
    c0, c1 = max(left, 0), min(left + cols, w)
    if r0 < r1 and c0 < c1:
        out[r0 - top : r1 - top, c0 - left : c1 - left] = image[r0:r1, c0:c1]


def coarse_search(edges: Edges, model: WallModel, cfg: RegistrationConfig,
                  scale_range: tuple[float, float]) -> list[Proposal]:
    """Global search over scale (``scale_range``, px/mm), rotation, mirror and centre (see the
    package docstring).

    For each scale the orientation field is shrunk so the phantom would appear at
    ``coarse_px_per_mm``; the rotation-averaged template (a ring detector) is correlated with
    it (summing ``Re(z · conj(t))`` over the template, centres up to a template size outside
    the frame) and its best peaks are kept; all rotations and both mirrors are then scored at
    those peaks by one matrix product of image patches with the template stack.

    The shrunk fields of all scales are laid out in one mosaic, a template size of zeros
    around each, so that one DFT of the mosaic, a product with the two mirrors' template
    spectra and one inverse DFT (:func:`_circular_ccorr_pair`) give every scale's detector:
    the values are those of a separate ``cv2.matchTemplate`` on each field zero-padded by a
    template size (up to float rounding), at a fraction of the cost.

    Returns the best ``cfg.n_candidates`` distinct proposals by score, then up to as many more,
    not near those, that are best by score over the square root of their patch's edge energy
    (a dense texture such as a wood-grained table outscores the walls in raw sums).
    """
    tpl = _cached_template_stack(model, cfg)
    size, c, n_rot = tpl.size, tpl.size // 2, len(tpl.rotations)
    lo, hi = scale_range
    n_scales = max(1, int(math.ceil(math.log(hi / lo) / math.log1p(cfg.coarse_scale_step))) + 1)
    scales = np.geomspace(lo, hi, n_scales)
    fields = [_shrunk_field(edges.pyramid, s / cfg.coarse_px_per_mm) for s in scales]
    offsets, (rows, cols), spectra = _coarse_plan(tpl, [z.shape[:2] for z, _, _ in fields])
    # the DFT wraps around: the zeros before the first shelf and column stand in for those
    # after the last
    mosaic = np.zeros((rows, cols, 2), np.float32)
    for (z, _, _), (oy, ox) in zip(fields, offsets):
        mosaic[oy : oy + z.shape[0], ox : ox + z.shape[1]] = z
    detector = _circular_ccorr_pair(mosaic, spectra)
    spots = []  # (scale, shrink x, shrink y, centre x, centre y) per patch
    windows = []  # (field, top row, left column) per patch
    for s, (z, fx, fy), (oy, ox) in zip(scales, fields, offsets):
        hk, wk = z.shape[:2]
        # this scale's field zero-padded by a template on each side (the spiral centre may
        # lie outside the frame) is the mosaic's [y0 : oy + hk + size, x0 : ox + wk + size]
        y0, x0 = oy - size, ox - size
        # its detector[u, v]: template's top-left at padded (u, v), i.e. at field (v - size,
        # u - size), its centre at image (v + c - size, u + c - size)
        for u, v in _peaks(detector[y0 : oy + hk + 1, x0 : ox + wk + 1], cfg.coarse_peaks_per_scale, radius=2):
            windows.append((z, u - size, v - size))
            spots.append((float(s), fx, fy, v + c - size, u + c - size))
    if not windows:
        return []
    patches = np.zeros((len(windows), size, size, 2), np.float32)
    for patch, (z, top, left) in zip(patches, windows):
        _copy_window(patch, z, top, left)
    # each patch as one row: its values on the rows of the template stack
    rows = patches.reshape(len(windows), 2 * size * size)[:, tpl.patch_index]
    scores = rows @ tpl.stack_real  # (n_spots, 2J)
    best = np.argmax(scores, axis=1)
    best_scores = scores[np.arange(len(scores)), best]
    # the same scores over the square root of each patch's edge energy: a dense texture (a
    # wood-grained table) matches part of the template everywhere and outscores the walls in raw
    # sums, not once its own density is divided out
    energy = np.sqrt(np.einsum("ij,ij->i", rows, rows, dtype=np.float64))
    relative = best_scores / np.maximum(energy, 1e-9) ** 0.5
    proposals: list[Proposal] = []
    for (s, fx, fy, ax, ay), j, score in zip(spots, best.tolist(), best_scores.tolist()):
        mirrored, rot = bool(j // n_rot), float(tpl.rotations[j % n_rot])
        cx, cy = (ax + 0.5) * fx - 0.5, (ay + 0.5) * fy - 0.5
        proposals.append(Proposal(score, CameraPose(cx, cy, wrap(rot), s, mirrored)))
    raw = distinct(sorted(proposals, key=lambda p: -p.score), cfg.n_candidates)
    by_density = distinct([proposals[i] for i in np.argsort(-relative, kind="stable")], cfg.n_candidates)
    return raw + [p for p in by_density if not any(_same_place(p, q) for q in raw)]


def _same_place(a: Proposal, b: Proposal) -> bool:
    """Whether two proposals are near-duplicates: same mirror, scales within 12 %, rotations
    within 0.15 rad and centres within half a millimetre."""
    p, q = a.pose, b.pose
    return (
        p.mirrored == q.mirrored
        and abs(math.log(p.px_per_mm / q.px_per_mm)) < 0.12
        and abs(wrap(p.rotation_rad - q.rotation_rad)) < 0.15
        and math.hypot(p.centre_x_px - q.centre_x_px, p.centre_y_px - q.centre_y_px) < 0.5 * p.px_per_mm
    )


def distinct(proposals: list[Proposal], n: int) -> list[Proposal]:
    """The best ``n`` proposals, skipping near-duplicates of better ones (:func:`_same_place`)."""
    out: list[Proposal] = []
    for p in proposals:
        if not any(_same_place(p, q) for q in out):
            out.append(p)
            if len(out) == n:
                break
    return out
