"""Geometry against independent references: an analytic ray-cast scene, brute-force FPS/kNN, scipy."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lerobot_obsbench import geometry


@pytest.fixture(scope="module")
def scene(synthetic_module):
    """A ray-cast frame (table plane + two boxes) with exact world hit points."""
    s = synthetic_module
    size = 48
    K = s.intrinsics(size)
    cam2world = s.look_at(eye=(0.45, 0.1, 0.55), target=(0.0, 0.0, 0.0))
    boxes = [(np.array([0.05, -0.05, 0.025]), 0.025, s.CUBE_RGB), (np.array([-0.1, 0.1, 0.2]), 0.015, s.GRIPPER_RGB)]
    rgb, depth, points = s.render(K, cam2world, size, boxes)
    return dict(K=K, cam2world=cam2world, rgb=rgb, depth=depth, points=points, size=size)


def _world_points(scene):
    depth_m = torch.tensor(scene["depth"][None, ..., 0].astype(np.float64) / 1000.0)
    K = torch.tensor(scene["K"])[None]
    cam = geometry.unproject_depth(depth_m, K)
    return geometry.transform_points(cam, torch.tensor(scene["cam2world"])[None])[0].numpy(), depth_m[0].numpy() > 0


def test_unprojection_recovers_raycast_points_in_world_frame(scene):
    world, valid = _world_points(scene)
    truth = scene["points"]
    assert valid.sum() > 0.9 * valid.size
    # depth is quantised to 1 mm along the ray, so points agree to ~1 mm * |ray| / z
    err = np.linalg.norm(world[valid] - truth[valid], axis=-1)
    assert err.max() < 1.5e-3
    # the table plane comes out at z = 0 and box tops at their height
    table = np.abs(truth[..., 2]) < 1e-9
    assert np.abs(world[valid & table][:, 2]).max() < 1.5e-3


def test_camera_and_ee_frames_match_explicit_transforms(scene):
    world, valid = _world_points(scene)
    truth = scene["points"][valid]
    # camera frame: inverse of cam2world applied by hand
    T = scene["cam2world"]
    cam_truth = (truth - T[:3, 3]) @ T[:3, :3]
    cam = geometry.transform_points(torch.tensor(world[valid])[None], geometry.invert_transform(torch.tensor(T)[None]))[
        0
    ]
    assert np.abs(cam.numpy() - cam_truth).max() < 1.5e-3
    # ee frame: a pose given as xyz + quaternion (w, x, y, z); reference rotation from scipy
    rot = Rotation.from_euler("xyz", [0.3, -0.2, 1.1])
    pos = np.array([0.1, -0.05, 0.3])
    xyzw = rot.as_quat()
    quat = torch.tensor([[xyzw[3], *xyzw[:3]]])
    ee_pose = geometry.pose_to_matrix(torch.tensor(pos)[None], quat)
    ee = geometry.transform_points(torch.tensor(world[valid])[None], geometry.invert_transform(ee_pose))[0].numpy()
    ee_truth = rot.inv().apply(truth - pos)
    assert np.abs(ee - ee_truth).max() < 1.5e-3


def test_quaternion_and_inverse_against_scipy():
    rots = Rotation.random(16, random_state=0)
    xyzw = rots.as_quat()
    quat = torch.tensor(np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1))
    mats = geometry.quaternion_to_matrix(quat).numpy()
    np.testing.assert_allclose(mats, rots.as_matrix(), atol=1e-12)
    T = geometry.pose_to_matrix(torch.randn(16, 3, dtype=torch.float64), quat)
    np.testing.assert_allclose(
        (geometry.invert_transform(T) @ T).numpy(), np.broadcast_to(np.eye(4), (16, 4, 4)), atol=1e-12
    )


def test_crop_mask_keeps_only_points_inside_the_box():
    pts = torch.tensor([[[0.0, 0.0, 0.1], [0.0, 0.0, 0.001], [2.0, 0.0, 0.1], [0.5, -0.5, 0.5]]])
    mask = torch.tensor([[True, True, True, False]])
    got = geometry.crop_mask(pts, mask, (-1, 1, -1, 1, 0.005, 1))
    assert got.tolist() == [[True, False, False, False]]
    # one box per cloud
    two = torch.cat([pts, pts])
    boxes = torch.tensor([[-1, 1, -1, 1, 0.005, 1], [-3, 3, -1, 1, 0.0, 1]])
    got = geometry.crop_mask(two, torch.cat([mask, mask]), boxes)
    assert got.tolist() == [[True, False, False, False], [True, True, True, False]]


def _padded_cloud(n_valid, n_pad, seed):
    g = torch.Generator().manual_seed(seed)
    b = len(n_valid)
    xyz = torch.rand(b, max(n_valid) + n_pad, 3, generator=g)
    mask = torch.zeros(b, xyz.shape[1], dtype=torch.bool)
    for i, n in enumerate(n_valid):
        # valid points scattered among padding, not only at the front
        mask[i, torch.randperm(xyz.shape[1], generator=g)[:n]] = True
    return xyz, mask


@pytest.mark.parametrize("random", [True, False])
def test_voxel_sample_keeps_exactly_one_point_per_occupied_voxel(random):
    xyz, mask = _padded_cloud([3000, 1200], 200, seed=0)
    xyz = xyz * 0.1  # 10 cm cube, 5 mm voxels: many points per voxel
    keep = geometry.voxel_sample(xyz, mask, 0.005, random=random, generator=torch.Generator().manual_seed(1))
    assert not (keep & ~mask).any()
    for b in range(2):
        cells_all = {tuple(c) for c in torch.floor(xyz[b][mask[b]] / 0.005).long().tolist()}
        cells_kept = [tuple(c) for c in torch.floor(xyz[b][keep[b]] / 0.005).long().tolist()]
        assert len(cells_kept) == len(set(cells_kept)) == len(cells_all)
        assert set(cells_kept) == cells_all


def test_voxel_sample_is_deterministic_in_eval_and_random_in_training():
    xyz, mask = _padded_cloud([2000], 0, seed=3)
    xyz = xyz * 0.05
    a = geometry.voxel_sample(xyz, mask, 0.005, random=False)
    b = geometry.voxel_sample(xyz, mask, 0.005, random=False)
    assert torch.equal(a, b)
    # eval keeps the lowest index in each voxel
    cells = torch.floor(xyz[0] / 0.005).long()
    first = {}
    for i in torch.nonzero(mask[0]).flatten().tolist():
        first.setdefault(tuple(cells[i].tolist()), i)
    assert sorted(first.values()) == torch.nonzero(a[0]).flatten().tolist()
    r1 = geometry.voxel_sample(xyz, mask, 0.005, random=True, generator=torch.Generator().manual_seed(0))
    r2 = geometry.voxel_sample(xyz, mask, 0.005, random=True, generator=torch.Generator().manual_seed(1))
    assert r1.sum() == r2.sum() == a.sum() and not torch.equal(r1, r2)


def _fps_reference(points: np.ndarray, k: int) -> list[int]:
    chosen = [0]
    dist = np.full(len(points), np.inf)
    for _ in range(k - 1):
        dist = np.minimum(dist, ((points - points[chosen[-1]]) ** 2).sum(1))
        chosen.append(int(dist.argmax()))
    return chosen


FPS_KERNEL = """
import sys, torch
from lerobot_obsbench import fps_triton
cloud = torch.load(sys.argv[1])
start = cloud["mask"].to(torch.uint8).argmax(dim=1)
torch.save(fps_triton.farthest_point_sample(cloud["xyz"], cloud["mask"], start, cloud["k"]), sys.argv[2])
"""


@pytest.fixture
def fps_triton_interpreted(tmp_path):
    """The CUDA FPS kernel run by Triton's interpreter on CPU tensors (CI has no GPU; the kernel is the same).
    A subprocess: the interpreter must be chosen before Triton is first imported."""

    def fps(xyz, mask, k):
        torch.save({"xyz": xyz, "mask": mask, "k": k}, tmp_path / "cloud.pt")
        env = {**os.environ, "TRITON_INTERPRET": "1"}
        command = [sys.executable, "-c", FPS_KERNEL, str(tmp_path / "cloud.pt"), str(tmp_path / "seeds.pt")]
        subprocess.run(command, env=env, check=True)
        return torch.load(tmp_path / "seeds.pt")

    return fps


@pytest.mark.parametrize("backend", ["fpsample", "torch", "triton"])
def test_fps_from_each_clouds_first_point_matches_brute_force(backend, request):
    """FPS from each cloud's first valid point, seed for seed a brute force's: on CPU with start="first" (the
    official point pipeline), and the GPU paths (tensor loop, Triton kernel) run on CPU tensors. Clouds on both
    sides of QUICK_FPS_MIN_POINTS (where start="any" takes QuickFPS's tree start), with more and fewer points than
    seeds, padding scattered among the points; random floats, so no distances tie."""
    quick = geometry.QUICK_FPS_MIN_POINTS
    counts = [quick + 476, quick, quick - 1, 300, 40]
    xyz, mask = _padded_cloud(counts, 30, seed=5)
    k = 64
    if backend == "fpsample":
        idx, seed_mask = geometry.farthest_point_sample(xyz, mask, k, start="first")
        assert (idx[-1, 40:] == idx[-1, 0]).all()  # invalid slots repeat the first seed
    else:
        fps = geometry._fps_torch if backend == "torch" else request.getfixturevalue("fps_triton_interpreted")
        idx = fps(xyz, mask, k)
        seed_mask = torch.arange(k)[None] < torch.tensor(counts)[:, None]
    for b, n in enumerate(counts):
        valid = torch.nonzero(mask[b]).flatten()
        picked = idx[b][seed_mask[b]]
        assert seed_mask[b].sum() == min(n, k) and mask[b, picked].all()
        if n > k:
            assert picked.tolist() == valid[_fps_reference(xyz[b, valid].double().numpy(), k)].tolist()
        else:
            assert sorted(picked.tolist()) == valid.tolist()


def test_fps_refuses_an_unknown_start():
    xyz, mask = _padded_cloud([50], 0, seed=0)
    with pytest.raises(ValueError, match="Unknown FPS start 'fast'; choose one of first, any"):
        geometry.farthest_point_sample(xyz, mask, 8, start="fast")


def test_fps_kernel_breaks_ties_like_the_tensor_loop_across_chunks(fps_triton_interpreted):
    """Points on an integer grid tie on exact distances, also between the kernel's 1,024-point chunks: the
    kernel must pick the lowest index, as the tensor loop (torch.argmax) does, seed for seed."""
    grid = torch.stack(torch.meshgrid(*[torch.arange(14.0)] * 3, indexing="ij"), -1).reshape(1, -1, 3)
    xyz = torch.cat([grid, grid.flip(1)])  # 2,744 points: three chunks
    mask = torch.ones(2, xyz.shape[1], dtype=torch.bool)
    mask[1, :5] = False  # the second cloud starts at its first valid point
    got = fps_triton_interpreted(xyz, mask, 40)
    assert got.tolist() == geometry._fps_torch(xyz, mask, 40).tolist()
    assert got[1, 0] == 5 and mask[1, got[1]].all()


@pytest.mark.parametrize("backend", ["kdtree", "dense"])
def test_knn_matches_brute_force_and_ignores_padding(backend):
    xyz, mask = _padded_cloud([200, 5], 20, seed=7)
    query = torch.rand(2, 17, 3)
    if backend == "dense":  # the GPU path, run here on CPU tensors
        idx = geometry._knn_dense(query, xyz, mask, k=8, chunk=5)
    else:
        idx = geometry.knn(query, xyz, mask, k=8)
    assert idx.shape == (2, 17, 8)
    for b in range(2):
        valid = torch.nonzero(mask[b]).flatten()
        d = ((query[b, :, None] - xyz[b, valid][None]) ** 2).sum(-1)
        order = valid[d.argsort(dim=1)]
        if len(valid) >= 8:
            got = geometry.gather(xyz, idx)[b]
            ref = xyz[b, order[:, :8]]
            np.testing.assert_allclose(
                ((got - query[b, :, None]) ** 2).sum(-1), ((ref - query[b, :, None]) ** 2).sum(-1), rtol=1e-5, atol=1e-7
            )
        else:
            # fewer valid points than k: the neighbours are all valid points, missing ones repeat the nearest
            assert mask[b, idx[b]].all()
            assert (idx[b, :, 0] == order[:, 0]).all()
            assert all(set(row.tolist()) == set(valid.tolist()) for row in idx[b])


def test_pack_moves_valid_entries_first_preserving_order():
    mask = torch.tensor([[False, True, False, True], [True, False, False, False]])
    values = torch.arange(8.0).reshape(2, 4)
    packed, new_mask = geometry.pack(mask, values)
    assert packed[0].tolist() == [1.0, 3.0] and packed[1, 0] == 4.0
    assert new_mask.tolist() == [[True, True], [True, False]]
