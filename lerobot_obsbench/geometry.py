"""Point-cloud geometry: unprojection, frames, cropping, voxel sampling, FPS and kNN.

Every function is pure, batched over a leading dimension B, and runs on whatever device its inputs live on.
Variable-size clouds are padded to a common length N with a boolean `mask` (B, N) marking real points.
Conventions (the dataset schema): depth is metres along the optical axis, K is OpenCV's (pixel (u, v) = (column, row),
integer coordinates at pixel centres), `cam2world` maps OpenCV camera coordinates (x right, y down,
z forward) to the world frame, quaternions are (w, x, y, z).
"""

from __future__ import annotations

import fpsample
import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from lerobot_obsbench.schema import check_choice


def unproject_depth(depth: Tensor, K: Tensor) -> Tensor:
    """Camera-frame points (B, H, W, 3) of a metric depth map (B, H, W) with intrinsics K (B, 3, 3)."""
    _, h, w = depth.shape
    v, u = torch.meshgrid(
        torch.arange(h, device=depth.device, dtype=depth.dtype),
        torch.arange(w, device=depth.device, dtype=depth.dtype),
        indexing="ij",
    )
    fx, fy = K[:, 0, 0, None, None], K[:, 1, 1, None, None]
    cx, cy = K[:, 0, 2, None, None], K[:, 1, 2, None, None]
    x = (u - cx) / fx * depth
    y = (v - cy) / fy * depth
    return torch.stack([x, y, depth], dim=-1)


SURFACE_SLOPE = 5.7  # tan(80 degrees): surfaces seen more obliquely than this count as occlusion edges


def register_depth(
    depth: Tensor,
    k_depth: Tensor,
    depth_to_color: Tensor,
    k_color: Tensor,
    size: tuple[int, int],
    steps: int = 3,
    tolerance: float = 1e-3,
) -> Tensor:
    """Depth maps (B, Hd, Wd) in metres seen by a depth camera, re-expressed as the colour camera sees them:
    (B, H, W) metres along the COLOUR camera's optical axis at the colour pixel centres, 0 where unknown.

    librealsense's `rs.align` writes each depth pixel's own (depth-camera) z into the colour pixel it lands on,
    which is exact only for a pure x-baseline; this function gives the colour-frame z. Two stages:
    1. splat: every valid depth pixel is unprojected with the depth intrinsics, moved into the colour frame by
       `depth_to_color` (B, 4, 4: depth-camera -> colour-camera coordinates) and projected to its nearest colour
       pixel; the nearest point wins (z-buffer). This starts each colour pixel (holes take their nearest
       neighbour's start) but is off by up to half a pixel's footprint on slanted surfaces.
    2. refine (`steps` fixed-point iterations): for each colour pixel, the point at depth z on its ray is moved
       into the depth camera and the depth map's inverse is interpolated bilinearly where it lands (exact on a
       plane, whose inverse depth is affine in pixel coordinates); z is updated so that the point lies on that
       surface. Pixels whose four depth neighbours are not one surface (occlusion edges: a jump larger than a
       surface turned ~80 degrees from the depth camera gives between neighbouring pixels, and at least 2% of
       the depth) or whose final residual exceeds `tolerance` metres are 0: the splatted value there is off by
       up to half a pixel's footprint, so it is dropped rather than kept."""
    b, hd, wd = depth.shape
    h, w = size
    dtype, device = depth.dtype, depth.device
    # 1. splat
    points = transform_points(unproject_depth(depth, k_depth).reshape(b, -1, 3), depth_to_color)
    z = points[..., 2]
    valid = (depth.reshape(b, -1) > 0) & (z > 0)
    safe_z = torch.where(valid, z, torch.ones_like(z))
    u = torch.round(k_color[:, 0, 0, None] * points[..., 0] / safe_z + k_color[:, 0, 2, None])
    v = torch.round(k_color[:, 1, 1, None] * points[..., 1] / safe_z + k_color[:, 1, 2, None])
    valid &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    pixel = (v * w + u).long().clamp(0, h * w - 1) + torch.arange(b, device=device)[:, None] * (h * w)
    far = torch.full((b * h * w,), float("inf"), dtype=dtype, device=device)
    splat = far.scatter_reduce(0, pixel[valid], z[valid], reduce="amin").reshape(b, 1, h, w)
    start = torch.where(torch.isinf(splat), -torch.nn.functional.max_pool2d(-splat, 3, 1, 1), splat)[:, 0]
    started = torch.isfinite(start)
    z_c = torch.where(started, start, torch.ones_like(start))
    # 2. refine: the colour ray's point z * ray, in depth-camera coordinates, is z * q + t
    ray = unproject_depth(torch.ones(b, h, w, dtype=dtype, device=device), k_color)  # (B, H, W, 3), z = 1
    color_to_depth = invert_transform(depth_to_color)
    q = ray.reshape(b, -1, 3) @ color_to_depth[:, :3, :3].transpose(1, 2)
    t = color_to_depth[:, None, :3, 3]
    flat_depth = depth.reshape(b, -1)
    corner_offsets = torch.tensor([0, 1, wd, wd + 1], device=device)
    # largest relative depth change between neighbouring depth pixels on one surface (tan 80 deg / focal length)
    one_surface_jump = (SURFACE_SLOPE / k_depth[:, 0, 0, None]).clamp(min=0.02)
    z_c = z_c.reshape(b, -1)
    for _ in range(steps + 1):
        p = z_c[..., None] * q + t
        pz = torch.where(p[..., 2] > 0, p[..., 2], torch.ones_like(p[..., 2]))
        ud = k_depth[:, 0, 0, None] * p[..., 0] / pz + k_depth[:, 0, 2, None]
        vd = k_depth[:, 1, 1, None] * p[..., 1] / pz + k_depth[:, 1, 2, None]
        x0, y0 = torch.floor(ud), torch.floor(vd)
        inside = (x0 >= 0) & (x0 < wd - 1) & (y0 >= 0) & (y0 < hd - 1) & (p[..., 2] > 0)
        base = (y0.clamp(0, hd - 2) * wd + x0.clamp(0, wd - 2)).long()
        # the four depth pixels around each landing point, in one gather: (B, N, 4) top-left, top-right, ...
        corners = flat_depth.gather(1, (base[..., None] + corner_offsets).reshape(b, -1)).reshape(b, -1, 4)
        fx, fy = (ud - x0).clamp(0, 1), (vd - y0).clamp(0, 1)
        c0, c1, c2, c3 = corners.unbind(-1)
        lo = torch.minimum(torch.minimum(c0, c1), torch.minimum(c2, c3))
        hi = torch.maximum(torch.maximum(c0, c1), torch.maximum(c2, c3))
        one_surface = inside & (lo > 0) & (hi - lo < one_surface_jump * hi)
        i0, i1, i2, i3 = (1 / c.clamp(min=1e-6) for c in (c0, c1, c2, c3))
        top = i0 + fx * (i1 - i0)
        surface = 1 / (top + fy * (i2 + fx * (i3 - i2) - top))
        residual = (p[..., 2] - surface).abs()
        z_c = torch.where(one_surface, (surface - t[..., 2]) / q[..., 2], z_c)
    refined = one_surface & (residual < tolerance) & started.reshape(b, -1)
    return torch.where(refined, z_c, torch.zeros_like(z_c)).reshape(b, h, w)


def transform_points(points: Tensor, transform: Tensor) -> Tensor:
    """Apply rigid transforms (B, 4, 4) to points (B, ..., 3)."""
    b = points.shape[0]
    flat = points.reshape(b, -1, 3)
    out = flat @ transform[:, :3, :3].transpose(1, 2) + transform[:, None, :3, 3]
    return out.reshape(points.shape)


def invert_transform(transform: Tensor) -> Tensor:
    """Inverse of rigid transforms (B, 4, 4) without a general matrix inverse."""
    rot_t = transform[:, :3, :3].transpose(1, 2)
    out = torch.zeros_like(transform)
    out[:, :3, :3] = rot_t
    out[:, :3, 3] = -(rot_t @ transform[:, :3, 3:4]).squeeze(-1)
    out[:, 3, 3] = 1
    return out


def rigidity_error(transform: Tensor) -> Tensor:
    """How far each (..., 4, 4) transform is from rigid: the largest of |R R^T - I|, |det R - 1| and the last
    row's deviation from (0, 0, 0, 1), per transform (...)."""
    rotation = transform[..., :3, :3]
    eye = torch.eye(3, dtype=transform.dtype, device=transform.device)
    orthonormal = (rotation @ rotation.transpose(-1, -2) - eye).abs().flatten(-2).amax(-1)
    determinant = (torch.linalg.det(rotation) - 1).abs()
    bottom = transform.new_tensor([0.0, 0.0, 0.0, 1.0])
    last_row = (transform[..., 3, :] - bottom).abs().amax(-1)
    return torch.stack([orthonormal, determinant, last_row], -1).amax(-1)


def quaternion_to_matrix(quat: Tensor) -> Tensor:
    """Rotation matrices (B, 3, 3) of quaternions (B, 4) in (w, x, y, z) order (normalised first)."""
    w, x, y, z = torch.unbind(quat / quat.norm(dim=-1, keepdim=True), dim=-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - z * w),
            2 * (x * z + y * w),
            2 * (x * y + z * w),
            1 - 2 * (x * x + z * z),
            2 * (y * z - x * w),
            2 * (x * z - y * w),
            2 * (y * z + x * w),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(quat.shape[:-1] + (3, 3))


def pose_to_matrix(position: Tensor, quat: Tensor) -> Tensor:
    """4x4 transforms (B, 4, 4) from positions (B, 3) and (w, x, y, z) quaternions (B, 4)."""
    out = torch.zeros(position.shape[0], 4, 4, dtype=position.dtype, device=position.device)
    out[:, :3, :3] = quaternion_to_matrix(quat)
    out[:, :3, 3] = position
    out[:, 3, 3] = 1
    return out


def box_pixel_window(
    K: Tensor, cam2world: Tensor, box: Tensor | tuple | list, height: int, width: int
) -> tuple[int, int, int, int] | None:
    """Rows v0:v1 and columns u0:u1 of a (height, width) image outside which no pixel can unproject into the box
    (xmin, xmax, ymin, ymax, zmin, zmax; world frame), for every camera of the batch (K (B, 3, 3), cam2world
    (B, 4, 4)); None when the box reaches behind a camera (no such window).

    With the box in front of the camera, the image of the box is the convex hull of its corners' images, and a
    pixel's unprojected point projects back onto that pixel: the corners' bounding rectangle holds every pixel
    the crop keeps.
    """
    bounds = torch.as_tensor(box, dtype=K.dtype, device=K.device).reshape(3, 2)
    corners = torch.cartesian_prod(bounds[0], bounds[1], bounds[2])  # (8, 3)
    cam = transform_points(corners.expand(len(K), 8, 3), invert_transform(cam2world.to(K.dtype)))
    if not bool((cam[..., 2] > 1e-6).all()):
        return None
    u = K[:, None, 0, 0] * cam[..., 0] / cam[..., 2] + K[:, None, 0, 2]
    v = K[:, None, 1, 1] * cam[..., 1] / cam[..., 2] + K[:, None, 1, 2]
    # one pixel of margin against rounding; an empty window keeps one pixel (it will be cropped away)
    u0 = min(max(int(torch.floor(u.min())) - 1, 0), width - 1)
    v0 = min(max(int(torch.floor(v.min())) - 1, 0), height - 1)
    u1 = max(min(int(torch.ceil(u.max())) + 2, width), u0 + 1)
    v1 = max(min(int(torch.ceil(v.max())) + 2, height), v0 + 1)
    return v0, v1, u0, u1


def shift_intrinsics(K: Tensor, rows: int, columns: int) -> Tensor:
    """Intrinsics (B, 3, 3) of the image cropped to start at row `rows`, column `columns`."""
    shifted = K.clone()
    shifted[:, 0, 2] -= columns
    shifted[:, 1, 2] -= rows
    return shifted


def crop_mask(points: Tensor, mask: Tensor, box: Tensor | tuple | list) -> Tensor:
    """Mask of points (B, N, 3) inside an axis-aligned box (xmin, xmax, ymin, ymax, zmin, zmax): one box (6,) for
    the batch or one per cloud (B, 6)."""
    box = torch.as_tensor(box, dtype=points.dtype, device=points.device).reshape(-1, 1, 3, 2)
    inside = ((points >= box[..., 0]) & (points <= box[..., 1])).all(dim=-1)
    return mask & inside


def pack(mask: Tensor, *values: Tensor) -> tuple[Tensor, ...]:
    """Move the masked entries of each (B, N, ...) tensor to the front, trimmed to the largest count.

    Returns the packed tensors followed by the new mask (B, M); the relative order of kept entries is preserved,
    and the slots after a cloud's own count hold its first unmasked entries, in order (a stable partition).
    """
    counts = mask.sum(dim=1)
    m = max(int(counts.max()) if mask.numel() else 0, 1)
    # each entry's place in the stable partition, from two running counts: O(N), where a sort is O(N log N)
    kept_before = mask.cumsum(dim=1) - 1
    dropped_before = (~mask).cumsum(dim=1) - 1
    destination = torch.where(mask, kept_before, counts[:, None] + dropped_before)
    order = torch.empty_like(destination).scatter_(
        1, destination, torch.arange(mask.shape[1], device=mask.device).expand_as(destination)
    )[:, :m]
    packed = [gather(v, order) for v in values]
    new_mask = torch.arange(m, device=mask.device)[None] < counts[:, None]
    return (*packed, new_mask)


def shuffle(mask: Tensor, *values: Tensor, generator: torch.Generator | None = None) -> tuple[Tensor, ...]:
    """Randomly reorder the masked entries of each (B, N, ...) tensor (padding stays last); returns the
    shuffled tensors followed by the mask."""
    keys = torch.rand(mask.shape, device=mask.device, generator=generator).masked_fill(~mask, 2.0)
    order = torch.argsort(keys, dim=1)
    return (*(gather(v, order) for v in values), gather(mask, order))


def gather(values: Tensor, index: Tensor) -> Tensor:
    """values (B, N, ...) indexed by index (B, ...) along dim 1 -> (B, ..., ...)."""
    b = values.shape[0]
    batch = torch.arange(b, device=values.device).view(b, *([1] * (index.dim() - 1)))
    return values[batch, index]


def voxel_grid(points: Tensor, mask: Tensor, voxel_size: float) -> tuple[Tensor, Tensor]:
    """Integer voxel coordinates (B, N, 3) of each point, relative to its cloud's lowest occupied voxel, and a
    voxel key (B, N) equal for two points exactly when they share a cloud and a voxel (-1 for padding). Keys
    sort by cloud, then x, y, z."""
    b = points.shape[0]
    cells = torch.floor(points / voxel_size).to(torch.int64)
    cells = cells - cells.masked_fill(~mask[..., None], torch.iinfo(torch.int64).max).amin(dim=1, keepdim=True)
    cells = cells.clamp(min=0)
    span = cells.masked_fill(~mask[..., None], 0).amax(dim=(0, 1)) + 1
    key = (cells[..., 0] * span[1] + cells[..., 1]) * span[2] + cells[..., 2]
    key = key + torch.arange(b, device=points.device)[:, None] * (span[0] * span[1] * span[2])
    return cells, key.masked_fill(~mask, -1)


def voxel_sample(
    points: Tensor, mask: Tensor, voxel_size: float, random: bool, generator: torch.Generator | None = None
) -> Tensor:
    """Keep exactly one point per occupied voxel of edge `voxel_size` (per batch element).

    Returns a keep-mask (B, N). `random=True` (training) picks a uniformly random point of each voxel;
    `random=False` (evaluation) deterministically keeps the lowest-index point.
    """
    b, n, _ = points.shape
    _, key = voxel_grid(points, mask, voxel_size)
    _, voxel_id = torch.unique(key.reshape(-1), return_inverse=True)
    if random:
        score = torch.randperm(b * n, device=points.device, generator=generator)
    else:
        score = torch.arange(b * n, device=points.device)
    best = torch.full((int(voxel_id.max()) + 1,), b * n, dtype=score.dtype, device=points.device)
    best = best.scatter_reduce(0, voxel_id, score, reduce="amin")
    keep = (best[voxel_id] == score).reshape(b, n)
    return keep & mask


def _fps_torch(xyz: Tensor, mask: Tensor, k: int) -> Tensor:
    """Batched farthest point sampling; starts from the first valid point of each cloud."""
    b, n, _ = xyz.shape
    idx = torch.zeros(b, k, dtype=torch.long, device=xyz.device)
    dist = torch.full((b, n), float("inf"), device=xyz.device, dtype=xyz.dtype).masked_fill(~mask, -1.0)
    current = mask.to(torch.uint8).argmax(dim=1)
    rows = torch.arange(b, device=xyz.device)
    for i in range(k):
        idx[:, i] = current
        d = ((xyz - xyz[rows, current][:, None]) ** 2).sum(-1)
        dist = torch.minimum(dist, d.masked_fill(~mask, -1.0))
        current = dist.argmax(dim=1)
    return idx


def _fps_cuda(xyz: Tensor, mask: Tensor, k: int) -> Tensor:
    """FPS in one Triton kernel launch (the tensor loop is launch-bound on a GPU); the loop where PyTorch was
    installed without Triton."""
    try:
        from lerobot_obsbench import fps_triton
    except ImportError:
        return _fps_torch(xyz, mask, k)
    return fps_triton.farthest_point_sample(xyz, mask, mask.to(torch.uint8).argmax(dim=1), k)


# Below this many points the exact per-point loop is as fast as building QuickFPS's tree.
QUICK_FPS_MIN_POINTS = 1024
# Where FPS starts: "first", each cloud's first valid point on every device (the paper's CUDA FPS, index 0);
# "any", wherever the device's fastest exact FPS starts (CPU: QuickFPS's KD-tree start on large clouds).
FPS_STARTS = ("first", "any")


def _fps_fpsample(xyz: Tensor, mask: Tensor, k: int, start: str = "first") -> Tensor:
    """Per-cloud exact FPS with `fpsample`'s C++ kernels, every seed the point farthest from the seeds before it.

    `start="first"` runs the per-point loop from each cloud's first valid point. `start="any"` runs QuickFPS
    (`bucket_fps_kdline_sampling`) on clouds of QUICK_FPS_MIN_POINTS or more, several times faster on the
    clouds the benchmark samples (docs/performance.md#measured-design-choices): the same rule, but fpsample 1.0
    reads the start index in its KD-tree's order (and none of its tree variants takes a start in the cloud's
    order), so the first seed is the point its tree lists first, and the seeds differ from the GPU paths'.
    """
    xyz_np = xyz.detach().cpu().numpy()
    mask_np = mask.cpu().numpy()
    out = np.zeros((xyz.shape[0], k), dtype=np.int64)
    for i in range(xyz.shape[0]):
        valid = np.flatnonzero(mask_np[i])
        if len(valid) <= k:  # every point is a seed: nothing to sample
            out[i, : len(valid)] = valid
            continue
        points = np.ascontiguousarray(xyz_np[i, valid], dtype=np.float32)
        if start == "any" and len(valid) >= QUICK_FPS_MIN_POINTS:
            picked = fpsample.bucket_fps_kdline_sampling(points, k, h=quick_fps_height(len(valid)), start_idx=0)
        else:
            picked = fpsample.fps_sampling(points, k, start_idx=0)
        out[i] = valid[picked.astype(np.int64)]
    return torch.from_numpy(out).to(xyz.device)


def quick_fps_height(n_points: int) -> int:
    """QuickFPS tree height (buckets of 2**h points): fpsample's advice, 5 for medium clouds and 7 for large
    ones, which is also the fastest on this package's clouds (docs/performance.md#measured-design-choices)."""
    return 5 if n_points < 16384 else 7


def farthest_point_sample(xyz: Tensor, mask: Tensor, k: int, start: str = "first") -> tuple[Tensor, Tensor]:
    """Indices (B, k) of k farthest-point seeds of each padded cloud, and their validity mask (B, k).

    A cloud with n ≤ k valid points returns all of them (in index order); the remaining k - n slots repeat
    its first point and are marked invalid (the reference CUDA FPS kernel repeats points the same way).
    `start` (FPS_STARTS): "first" starts each cloud at its first valid point on every device, as the paper's CUDA
    FPS does; "any" lets CPU start large clouds where QuickFPS's tree starts (`_fps_fpsample`), for speed where
    parity with the paper and across devices matters less. GPUs start at the first point either way.
    """
    check_choice("FPS start", start, FPS_STARTS)
    counts = mask.sum(dim=1)
    seed_mask = torch.arange(k, device=xyz.device)[None] < counts[:, None]
    if bool((counts <= k).all()):
        idx = pack(mask, torch.arange(xyz.shape[1], device=xyz.device).expand(xyz.shape[0], -1))[0]
        idx = torch.nn.functional.pad(idx, (0, max(0, k - idx.shape[1])))[:, :k]
    elif xyz.device.type == "cpu":
        idx = _fps_fpsample(xyz, mask, k, start)
    elif xyz.device.type == "cuda":
        idx = _fps_cuda(xyz, mask, k)
    else:
        idx = _fps_torch(xyz, mask, k)
    first = idx[:, :1].expand(-1, k)
    return torch.where(seed_mask, idx, first), seed_mask


def _knn_kdtree(query: Tensor, points: Tensor, mask: Tensor, k: int) -> Tensor:
    """Per-cloud kNN with scipy's KD-tree (on the CPU, far faster than a dense distance matrix:
    docs/performance.md#measured-design-choices), queries spread over every core (an exact search: the result
    does not depend on the number of workers)."""
    query_np, points_np, mask_np = query.detach().numpy(), points.detach().numpy(), mask.numpy()
    out = np.zeros(query.shape[:2] + (k,), dtype=np.int64)
    for i in range(query.shape[0]):
        valid = np.flatnonzero(mask_np[i])
        if len(valid) == 0:
            continue
        _, nearest = cKDTree(points_np[i, valid]).query(query_np[i], k=k, workers=-1)
        nearest = nearest.reshape(len(query_np[i]), k)
        missing = nearest >= len(valid)  # fewer than k points: scipy pads with n
        nearest[missing] = np.broadcast_to(nearest[:, :1], nearest.shape)[missing]
        out[i] = valid[nearest]
    return torch.from_numpy(out)


def knn(query: Tensor, points: Tensor, mask: Tensor, k: int, chunk: int = 1024) -> Tensor:
    """Indices (B, S, k) of the k nearest valid points (B, N, 3) of each query point (B, S, 3).

    Where a cloud has fewer than k valid points the missing neighbours repeat the nearest one, so that a
    max-pool over neighbours is unaffected. On CPU a KD-tree per cloud; elsewhere batched distance matrices,
    processed in chunks of queries to bound memory.
    """
    if query.device.type == "cpu":
        return _knn_kdtree(query, points, mask, k)
    return _knn_dense(query, points, mask, k, chunk)


def _knn_dense(query: Tensor, points: Tensor, mask: Tensor, k: int, chunk: int = 1024) -> Tensor:
    k_eff = min(k, points.shape[1])
    out = []
    for start in range(0, query.shape[1], chunk):
        d = torch.cdist(query[:, start : start + chunk], points)
        d = d.masked_fill(~mask[:, None, :], float("inf"))
        dist, idx = torch.topk(d, k_eff, dim=-1, largest=False)
        idx = torch.where(torch.isinf(dist), idx[..., :1], idx)
        out.append(idx)
    idx = torch.cat(out, dim=1)
    if k_eff < k:
        idx = torch.cat([idx, idx[..., :1].expand(-1, -1, k - k_eff)], dim=-1)
    return idx
