"""What the recovery reads from images: silhouettes, wrinkle density, person and garment masks.

* **Silhouette** (*thesis* Eq. 6.11): the simulated garment's vertices are projected with the
  scene camera and the union of its projected triangles is rasterised; the body's capsules are
  rasterised as thick segments. :class:`SilhouetteTarget` holds a target mask with the
  distance transform of its outline, and :meth:`SilhouetteTarget.distance` is the polygon
  distance of Eq. 6.10: the mean distance [px] of each outline's points to the other outline,
  symmetrised, plus the fraction of pixels where the masks disagree (which keeps a silhouette
  that is wholly inside the other from scoring zero).
* **Wrinkle density** P (*thesis* §6.4.2): ridges and valleys of the log-luminance inside the
  garment (eigenvalues of the Hessian at a scale of :data:`WRINKLE_SIGMA_PX`; the logarithm
  makes them invariant to the light's intensity and colour), thinned to one-pixel lines by
  non-maximum suppression across the fold, thresholded, and measured as line length per
  garment area [1/m] in each region, a band along the garment's outline left out. The
  *thesis* counts folds from paired edges; a length density is the stable version of the
  same count at these resolutions.
* **Parsing**: the person from the background with GrabCut (rectangle seed), the garment from
  the person with GrabCut seeded by the fitted body (:func:`parse_garment`).

OpenCV and scikit-image are imported inside the functions (the simulator package imports only
torch and numpy at module level).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = [
    "WRINKLE_SIGMA_PX",
    "SilhouetteTarget",
    "capsule_mask",
    "mesh_mask",
    "parse_garment",
    "parse_person",
    "region_map",
    "wrinkle_density",
    "wrinkle_lines",
]

WRINKLE_SIGMA_PX = 2.0
"""Scale of the ridge/valley detector [px]."""
WRINKLE_THRESHOLD = 0.025
"""Smallest scale-normalised Hessian eigenvalue of log-luminance that counts as a wrinkle."""
OUTLINE_BAND_PX = 3
"""Width of the band along the garment's outline left out of the wrinkle search [px]."""


def mesh_mask(pixels: np.ndarray, tri: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Union of projected triangles, bool (H, W); ``pixels`` (V, 2) in px (x right, y down)."""
    import cv2

    mask = np.zeros(shape, np.uint8)
    pts = np.round(pixels[tri] * 16).astype(np.int32)  # 4 fractional bits
    # One triangle at a time: ``fillPoly`` over many contours fills by parity, so where two
    # layers of a garment overlap (front and back panels) and along shared edges it leaves
    # holes instead of the union.
    for p in pts:
        cv2.fillConvexPoly(mask, p, 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def capsule_mask(camera, capsules: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Projected body primitives ``[p0, p1, r]`` (C, 7) as a bool mask (H, W).

    A pixel is in when its centre lies within the projected radius of the projected segment,
    as the renderer's coverage decides (a thick-line raster grows every limb by about a pixel,
    which biases a fit against a rendered silhouette).
    """
    ends = np.concatenate([capsules[:, :3], capsules[:, 3:6]])
    px, depth = camera.project(ends)
    focal = 0.5 * camera.height / np.tan(np.radians(camera.yfov_deg) / 2)
    count = len(capsules)
    radius = capsules[:, 6] * focal / np.maximum(0.5 * (depth[:count] + depth[count:]), 1e-6)
    a, b = px[:count], px[count:]
    lo = np.floor(np.minimum(a, b) - radius[:, None]).astype(np.int64).clip(0, None)
    hi = np.ceil(np.maximum(a, b) + radius[:, None]).astype(np.int64) + 1
    mask = np.zeros(shape, bool)
    for c in range(count):
        x0, y0 = lo[c]
        x1, y1 = min(hi[c, 0], shape[1]), min(hi[c, 1], shape[0])
        if x1 <= x0 or y1 <= y0:
            continue
        xs = np.arange(x0, x1) + 0.5 - a[c, 0]
        ys = np.arange(y0, y1) + 0.5 - a[c, 1]
        d = b[c] - a[c]
        t = np.clip((xs[None] * d[0] + ys[:, None] * d[1]) / max(float(d @ d), 1e-12), 0, 1)
        dx, dy = xs[None] - t * d[0], ys[:, None] - t * d[1]
        mask[y0:y1, x0:x1] |= dx * dx + dy * dy <= radius[c] ** 2
    return mask


def _outline_points(mask: np.ndarray) -> np.ndarray:
    """Pixel coordinates (x, y) of a mask's boundary pixels, shape (N, 2)."""
    import cv2

    m = mask.astype(np.uint8)
    eroded = cv2.erode(m, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    ys, xs = np.nonzero(m & ~eroded.astype(bool))
    return np.stack([xs, ys], -1)


def _outline_distance(mask: np.ndarray) -> np.ndarray:
    """Distance of every pixel to the mask's outline [px], float32 (H, W)."""
    import cv2

    edge = np.ones(mask.shape, np.uint8)
    pts = _outline_points(mask)
    edge[pts[:, 1], pts[:, 0]] = 0
    return cv2.distanceTransform(edge, cv2.DIST_L2, 5)


@dataclasses.dataclass(frozen=True)
class SilhouetteTarget:
    """A target silhouette prepared for Eq. 6.10 distances."""

    mask: np.ndarray
    """Target mask, bool (H, W)."""
    outline_dt: np.ndarray
    """Distance to the target's outline [px], float32 (H, W)."""
    outline: np.ndarray
    """The target outline's pixels (x, y), int (N, 2)."""

    @staticmethod
    def from_mask(mask: np.ndarray) -> SilhouetteTarget:
        """Prepare a bool mask (H, W)."""
        mask = np.asarray(mask, dtype=bool)
        return SilhouetteTarget(mask, _outline_distance(mask), _outline_points(mask))

    def distance(self, mask: np.ndarray) -> float:
        """Symmetric mean outline distance [px] plus 100 x the disagreeing fraction of pixels."""
        if not mask.any():
            return float("inf")
        ours = _outline_points(mask)
        forward = float(self.outline_dt[ours[:, 1], ours[:, 0]].mean())
        backward = float(_outline_distance(mask)[self.outline[:, 1], self.outline[:, 0]].mean())
        union = np.count_nonzero(mask | self.mask)
        xor = np.count_nonzero(mask ^ self.mask) / max(union, 1)
        return 0.5 * (forward + backward) + 100.0 * xor

    def iou(self, mask: np.ndarray) -> float:
        """Intersection over union with ``mask``."""
        union = np.count_nonzero(mask | self.mask)
        return np.count_nonzero(mask & self.mask) / max(union, 1)


def region_map(
    camera, capsules: np.ndarray, primitive_regions: np.ndarray, mask: np.ndarray
) -> np.ndarray:
    """Region id of every pixel of ``mask`` (the nearest projected primitive's), int (H, W).

    ``primitive_regions`` (C,) maps each body primitive to a region id (-1: none). Pixels
    outside ``mask`` get -1.
    """
    ends = np.concatenate([capsules[:, :3], capsules[:, 3:6]])
    px, _ = camera.project(ends)
    count = len(capsules)
    a, b = px[:count], px[count:]
    keep = primitive_regions >= 0
    ys, xs = np.nonzero(mask)
    pts = np.stack([xs + 0.5, ys + 0.5], -1).astype(np.float64)
    best = np.full(len(pts), np.inf)
    label = np.full(len(pts), -1, dtype=np.int64)
    for c in np.nonzero(keep)[0]:
        ab = b[c] - a[c]
        t = np.clip(((pts - a[c]) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        d = np.linalg.norm(pts - (a[c] + t[:, None] * ab), axis=1)
        closer = d < best
        best[closer] = d[closer]
        label[closer] = primitive_regions[c]
    out = np.full(mask.shape, -1, dtype=np.int64)
    out[ys, xs] = label
    return out


def wrinkle_lines(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """One-pixel wrinkle lines (ridges and valleys of log-luminance) inside ``mask``, bool.

    The stronger of the Hessian's two eigenvalues (valleys: the positive one; crests: the
    negative one) at scale :data:`WRINKLE_SIGMA_PX`, scale-normalised, thinned by
    non-maximum suppression across the fold (along the eigenvector) and thresholded at
    :data:`WRINKLE_THRESHOLD`.

    Args:
        image: RGB, uint8 (H, W, 3).
        mask: garment pixels, bool (H, W).
    """
    import cv2
    from scipy.ndimage import map_coordinates
    from skimage.feature import hessian_matrix

    inside = np.asarray(mask, dtype=bool)
    if not inside.any():
        return np.zeros_like(inside)
    gray = cv2.cvtColor(np.asarray(image, np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float64)
    logl = np.log(gray + 8.0)
    # Fill the outside with the garment's mean so the outline does not read as a fold.
    filled = np.where(inside, logl, logl[inside].mean())
    s = WRINKLE_SIGMA_PX
    hrr, hrc, hcc = hessian_matrix(filled, sigma=s, order="rc", use_gaussian_derivatives=False)
    mean = 0.5 * (hrr + hcc)
    rad = np.sqrt(0.25 * (hrr - hcc) ** 2 + hrc**2)
    lam_hi, lam_lo = mean + rad, mean - rad
    valley = lam_hi >= -lam_lo
    lam = np.where(valley, lam_hi, lam_lo)
    strength = s * s * np.abs(lam)
    # Eigenvector (row, col components) of the chosen eigenvalue: across the fold.
    vr = np.where(np.abs(hrr - lam) > np.abs(hcc - lam), hrc, lam - hcc)
    vc = np.where(np.abs(hrr - lam) > np.abs(hcc - lam), lam - hrr, hrc)
    norm = np.hypot(vr, vc)
    vr, vc = vr / np.maximum(norm, 1e-12), vc / np.maximum(norm, 1e-12)
    rows, cols = np.indices(strength.shape, dtype=np.float64)
    ahead = map_coordinates(strength, [rows + vr, cols + vc], order=1, mode="nearest")
    behind = map_coordinates(strength, [rows - vr, cols - vc], order=1, mode="nearest")
    peak = (strength >= ahead) & (strength >= behind)
    band = cv2.erode(inside.astype(np.uint8), np.ones((2 * OUTLINE_BAND_PX + 1,) * 2, np.uint8))
    return peak & (strength > WRINKLE_THRESHOLD) & band.astype(bool)


def wrinkle_density(
    image: np.ndarray, mask: np.ndarray, regions: np.ndarray, region_count: int, pixel_size: float
) -> tuple[np.ndarray, np.ndarray]:
    """Wrinkle line length per garment area in each region [1/m], and region areas [px].

    Args:
        image: RGB, uint8 (H, W, 3).
        mask: garment pixels, bool (H, W).
        regions: region id per pixel, int (H, W) (see :func:`region_map`).
        region_count: R.
        pixel_size: metres per pixel at the garment [m].

    Returns:
        ``(P (R,) [1/m], area (R,) [px])``; a region with no pixels gets P = 0.
    """
    lines = wrinkle_lines(image, mask)
    density = np.zeros(region_count)
    area = np.zeros(region_count)
    for r in range(region_count):
        inside = mask & (regions == r)
        area[r] = np.count_nonzero(inside)
        if area[r] > 0:
            density[r] = np.count_nonzero(lines & inside) / (area[r] * pixel_size)
    return density, area


def parse_person(image: np.ndarray, *, margin: float = 0.03, iterations: int = 5) -> np.ndarray:
    """Person (foreground) mask of an RGB image by GrabCut seeded with an inset rectangle."""
    import cv2

    img = cv2.cvtColor(np.asarray(image, np.uint8), cv2.COLOR_RGB2BGR)
    h, w = img.shape[:2]
    rect = (int(margin * w), int(margin * h), int((1 - 2 * margin) * w), int((1 - 2 * margin) * h))
    mask = np.zeros((h, w), np.uint8)
    bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.setRNGSeed(0)
    cv2.grabCut(img, mask, rect, bgd, fgd, iterations, cv2.GC_INIT_WITH_RECT)
    person = (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)
    return _largest_component(person)


def parse_garment(
    image: np.ndarray, person: np.ndarray, expected: np.ndarray, *, iterations: int = 5
) -> np.ndarray:
    """Garment mask inside ``person`` by GrabCut seeded with where the body fit expects it.

    Args:
        image: RGB, uint8 (H, W, 3).
        person: person mask, bool (H, W).
        expected: pixels where the fitted body says the garment should be, bool (H, W).
        iterations: GrabCut iterations.
    """
    import cv2

    img = cv2.cvtColor(np.asarray(image, np.uint8), cv2.COLOR_RGB2BGR)
    mask = np.full(person.shape, cv2.GC_BGD, np.uint8)
    mask[person] = cv2.GC_PR_BGD
    core = cv2.erode(expected.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    mask[person & expected] = cv2.GC_PR_FGD
    mask[person & core] = cv2.GC_FGD
    if not (mask == cv2.GC_FGD).any() or not (mask == cv2.GC_PR_BGD).any():
        return person & expected
    bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.setRNGSeed(0)
    cv2.grabCut(img, mask, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    garment = ((mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)) & person
    return _largest_component(garment)


def _largest_component(mask: np.ndarray) -> np.ndarray:
    import cv2

    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), 8)
    if count <= 1:
        return mask.astype(bool)
    keep = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return labels == keep
