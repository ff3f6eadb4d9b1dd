"""Small builders shared by the tests."""

from __future__ import annotations

import contextlib

import numpy as np
import torch

CAM = "base_camera"


@contextlib.contextmanager
def one_thread():
    """Run torch (and spconv's CPU kernels, which use torch's thread pool) on one thread: their reductions
    then add in a fixed order, so results do not depend on the machine's core count."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def frame_batch(synthetic, batch_size: int = 2, size: int = 32, seed: int = 0, cam: str = CAM) -> dict:
    """A batch shaped like LeRobot's (float CHW rgb, int64 depth (H,W,1), K, cam2world, state) from the
    analytic scene, plus the cubes' true world positions under "cube"."""
    rng = np.random.default_rng(seed)
    K = synthetic.intrinsics(size)
    cam2world = synthetic.look_at(eye=(0.45, 0.0, 0.55), target=(0.0, 0.0, 0.0))
    out = {k: [] for k in ("rgb", "depth", "state", "cube")}
    for _ in range(batch_size):
        cube = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), synthetic.CUBE_HALF])
        ee = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), 0.2])
        rgb, depth, _ = synthetic.render(
            K,
            cam2world,
            size,
            [(cube, synthetic.CUBE_HALF, synthetic.CUBE_RGB), (ee, synthetic.GRIPPER_HALF, synthetic.GRIPPER_RGB)],
        )
        out["rgb"].append(torch.tensor(rgb).permute(2, 0, 1).float() / 255)
        out["depth"].append(torch.tensor(depth.astype(np.int64)))
        out["state"].append(torch.tensor(np.concatenate([np.zeros(8), ee, synthetic.quat_z(0.7)]), dtype=torch.float32))
        out["cube"].append(torch.tensor(cube))
    return {
        f"observation.images.{cam}": torch.stack(out["rgb"]),
        f"observation.depth.{cam}": torch.stack(out["depth"]),
        f"observation.intrinsics.{cam}": torch.tensor(K, dtype=torch.float32).expand(batch_size, 3, 3).clone(),
        f"observation.cam2world.{cam}": torch.tensor(cam2world, dtype=torch.float32).expand(batch_size, 4, 4).clone(),
        "observation.state": torch.stack(out["state"]),
        "cube": torch.stack(out["cube"]),
    }


def training_setup(policy_type: str, obs_space: str, root, preset: str = "tiny", named: str | None = None, **overrides):
    """(policy, preprocessor, dataset) built the way lerobot-train builds them, for in-process tests; `named`: a
    named type (act_pcd, ...) of `policy_type` on `obs_space` to build instead."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    from lerobot_obsbench.presets import preset_overrides

    fields = {**preset_overrides(preset, policy_type, obs_space, overrides.get("encoder")), **overrides}
    fields.setdefault("workspace", [-0.5, 0.5, -0.5, 0.5, 0.005, 0.5])
    cfg = PreTrainedConfig.get_choice_class(named or policy_type)(obs_space=obs_space, device="cpu", **fields)
    meta = LeRobotDatasetMetadata("local/test", root=root)
    policy = make_policy(cfg, ds_meta=meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    dataset = LeRobotDataset("local/test", root=root, delta_timestamps=resolve_delta_timestamps(cfg, meta))
    return policy, pre, post, dataset


def first_batch(dataset, preprocessor, batch_size: int = 4, shuffle: bool = False, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=shuffle, generator=g)
    return preprocessor(next(iter(loader)))
