"""What a researcher reads before trusting a column of the report, computed per trained run:

- `loss_curve`: the training loss logged by lerobot-train, step by step;
- `open_loop_error`: the trained policy's action error on held-out demonstrations (recorded with the training demos,
  never trained on): the predicted chunk against the demonstrated one, mean absolute error in normalised action
  units. A seeing policy that has learned the task predicts held-out demonstrations better than the blind control;
- `object_pixels` (spaces that read a camera): how large the task's objects (`Task.objects`) appear, the diameter
  of each object's bounding sphere in pixels at the grid's resolution, from the recorded intrinsics and pose;
- `object_token_share` (point clouds): the share of the policy's point tokens (FPS seeds over its cropped,
  voxelised cloud) that land on the task's objects (within their bounding spheres). At a share near 0 a point-cloud
  policy cannot see the object whatever its training budget.

Object positions come from the demonstrations' `observation.privileged_state`, so the image and point-cloud checks
need a simulated dataset; everything else works on any dataset.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from lerobot_obsbench.schema import (
    LOCAL_REPO_ID,
    POSE_SIZE,
    PRIVILEGED_STATE_KEY,
    PointCloud,
    cam2world_key,
    intrinsics_key,
    reads_points,
)

LOSS_PATTERN = re.compile(r"(?<!\w)step:(\d+)([KMB]?)\s.*?(?<!\w)loss:([0-9.eE+-]+)")
# the line the grid's train unit writes before each lerobot-train start (units.train_unit)
START_PATTERN = re.compile(r"^=== \S+ (?:resuming at step (\d+)|starting) ===")


def loss_curve(log_text: str, log_every: int) -> list[list[float]]:
    """[[step, loss], ...] from a grid run's lerobot-train log (its `step:N ... loss:X` lines: the total loss, not
    l1_loss), logged every `log_every` steps.

    lerobot-train prints steps from 1,000 on rounded to thousands ("step:2K"), so such a line's step is the next
    multiple of `log_every` after the previous line's, or after the step a resumed run started from."""
    curve: dict[int, float] = {}
    last = 0
    for line in log_text.replace("\r", "\n").splitlines():
        start = START_PATTERN.search(line)
        if start:
            last = int(start.group(1) or 0)
            continue
        found = LOSS_PATTERN.search(line)
        if found:
            value, rounded, loss = found.groups()
            last = (last // log_every + 1) * log_every if rounded else int(value)
            curve[last] = float(loss)
    return [[step, loss] for step, loss in sorted(curve.items())]


def object_positions(privileged: np.ndarray, actors: tuple[str, ...], objects: dict[str, float]) -> dict:
    """{object: (positions (N, 3), radius)} from privileged states (N, 7 * O) recorded in `actors` order."""
    return {
        name: (privileged[:, actors.index(name) * POSE_SIZE : actors.index(name) * POSE_SIZE + 3], radius)
        for name, radius in objects.items()
    }


def pixel_diameters(positions: np.ndarray, radius: float, K: np.ndarray, cam2world: np.ndarray) -> np.ndarray:
    """Projected diameter in pixels of a sphere of `radius` at world `positions` (N, 3), seen by OpenCV cameras
    (K (N, 3, 3), cam2world (N, 4, 4)); 0 where the sphere's centre is behind the camera."""
    world2cam = np.linalg.inv(cam2world)
    depth = np.einsum("nj,nj->n", world2cam[:, 2, :3], positions) + world2cam[:, 2, 3]
    return np.where(depth > 0, 2 * radius * K[:, 0, 0] / np.maximum(depth, 1e-6), 0.0)


def token_share(xyz, mask, num_tokens: int, centres, radii, fps_start: str) -> float:
    """Share of the `num_tokens` FPS seeds (started as `fps_start`, geometry.FPS_STARTS) of padded clouds
    (xyz (B, N, 3), mask (B, N)) that lie within `radii` (list of floats) of the matching `centres` (list of
    (B, 3) tensors); invalid seed slots are not counted."""
    import torch

    from lerobot_obsbench import geometry

    idx, valid = geometry.farthest_point_sample(xyz, mask, num_tokens, fps_start)
    seeds = geometry.gather(xyz, idx)  # (B, k, 3)
    on_object = torch.zeros_like(valid)
    for centre, radius in zip(centres, radii, strict=True):
        on_object |= (seeds - centre[:, None]).norm(dim=-1) <= radius
    return float((on_object & valid).sum() / valid.sum().clamp_min(1))


def held_out_diagnostics(checkpoint: str | Path, dataset: str | Path, episodes: list[int], task, device="cpu") -> dict:
    """The checkpoint's diagnostics on the held-out demonstration `episodes` of `dataset` (see the module
    docstring); `task` is the task's `Task` (its privileged actors and objects)."""
    import torch
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

    from lerobot_obsbench.dataset_reads import every_feature
    from lerobot_obsbench.encoders.point_tokenizer import FPS_START
    from lerobot_obsbench.policies.loading import load_policy

    policy, pre, _ = load_policy(checkpoint, device)
    config = policy.config
    meta = LeRobotDatasetMetadata(LOCAL_REPO_ID, root=dataset)
    # every feature, not only the policy's: the diagnostics also read the object poses, K and cam2world
    delta_timestamps = every_feature(resolve_delta_timestamps(config, meta))
    data = LeRobotDataset(LOCAL_REPO_ID, root=dataset, episodes=episodes, delta_timestamps=delta_timestamps)
    errors, shares, pixels = [], [], {}
    has_objects = bool(task.objects) and PRIVILEGED_STATE_KEY in meta.features
    adapter = policy.observation_encoder().adapter  # in eval mode, as load_policy returns the policy
    cam = config.cameras[0] if config.cameras else None  # the controls read no camera
    loader = torch.utils.data.DataLoader(data, batch_size=32, shuffle=False)
    # Diffusion Policy's open-loop actions are sampled: from a fixed seed, so the figures do not depend on what the
    # process drew before (another unit in the same worker, another engine)
    with torch.random.fork_rng(devices=range(torch.cuda.device_count())), torch.inference_mode():
        torch.manual_seed(0)
        for batch in loader:
            batch = pre(batch)
            errors.append(policy.open_loop_error(batch).cpu())
            if not has_objects:
                continue
            # the current frame (Diffusion Policy's batches stack n_obs_steps frames)
            frame = {
                k: v[:, -1] if v.dim() > 1 and k in data.delta_timestamps and k != "action" else v
                for k, v in batch.items()
                if torch.is_tensor(v)
            }
            privileged = frame[PRIVILEGED_STATE_KEY].cpu().numpy()
            found = object_positions(privileged, task.privileged_actors, task.objects)
            if cam and intrinsics_key(cam) in frame:
                K, cam2world = frame[intrinsics_key(cam)].cpu().numpy(), frame[cam2world_key(cam)].cpu().numpy()
                for name, (positions, radius) in found.items():
                    pixels.setdefault(name, []).append(pixel_diameters(positions, radius, K, cam2world))
            if reads_points(config.obs_space) and config.frame == "world":
                inputs = adapter(policy.calibrated_depth(frame))  # a fused space's: one input per part
                cloud = next(
                    x for x in (inputs if isinstance(inputs, tuple) else (inputs,)) if isinstance(x, PointCloud)
                )
                centres = [torch.as_tensor(p, dtype=cloud.xyz.dtype) for p, _ in found.values()]
                radii = [r for _, r in found.values()]
                # the seeds the policy's tokenizer picks: its pipeline's FPS start
                fps_start = FPS_START[config.point_pipeline]
                share = token_share(cloud.xyz, cloud.mask, config.num_tokens, centres, radii, fps_start)
                shares.append((share, int(cloud.mask.shape[0])))
    out: dict = {"held_out_episodes": list(episodes), "open_loop_error": round(float(torch.cat(errors).mean()), 4)}
    if pixels:
        out["object_pixels"] = {name: round(float(np.concatenate(v).mean()), 2) for name, v in pixels.items()}
    if shares:
        total = sum(n for _, n in shares)
        out["object_token_share"] = round(sum(s * n for s, n in shares) / total, 4)
    return out
