"""The inference fast path (benchmarks/bench_latency.py): each shortcut against the code path it replaces, on
ray-cast frames and random clouds; and the rollout's real-time tools."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from lerobot_obsbench import geometry
from lerobot_obsbench.encoders import make_encoder
from lerobot_obsbench.robots.realtime import AsyncChunks, StepTimer
from lerobot_obsbench.spaces import AdapterConfig, ObservationAdapter
from tests.support.helpers import frame_batch


def _sort_pack(mask, *values):
    """The former pack: a stable sort of the mask."""
    counts = mask.sum(1)
    m = max(int(counts.max()), 1)
    order = torch.sort((~mask).to(torch.uint8), dim=1, stable=True).indices[:, :m]
    return (*(geometry.gather(v, order) for v in values), torch.arange(m)[None] < counts[:, None])


def test_pack_equals_a_stable_sort_entry_for_entry():
    g = torch.Generator().manual_seed(0)
    for density in (0.0, 0.05, 0.5, 1.0):
        mask = torch.rand(4, 700, generator=g) < density
        values = torch.randn(4, 700, 3, generator=g)
        ids = torch.arange(700).expand(4, -1)
        for got, want in zip(geometry.pack(mask, values, ids), _sort_pack(mask, values, ids), strict=True):
            assert torch.equal(got, want)


@pytest.fixture(scope="module")
def wide_batch(synthetic_module):
    return frame_batch(synthetic_module, batch_size=3, size=64)


@pytest.mark.parametrize(
    "workspace",
    [
        (-0.15, 0.15, -0.15, 0.15, 0.005, 0.3),  # a small box: a small window
        (-1.0, 1.0, -1.0, 1.0, 0.005, 1.0),  # the default box reaches behind the camera: no window
    ],
)
@pytest.mark.parametrize("training", [False, True])
def test_pixel_window_keeps_the_same_cloud(wide_batch, workspace, training, monkeypatch):
    """Unprojecting only the window of pixels that can land in the box gives the cloud of the whole frame,
    point for point, in evaluation and in training (same random draws)."""
    adapter = ObservationAdapter(
        AdapterConfig("pointcloud", ["base_camera"], workspace=workspace, workspace_jitter=0.01)
    )
    adapter.train(training)
    torch.manual_seed(3)
    fast = adapter(wide_batch)
    monkeypatch.setattr(geometry, "box_pixel_window", lambda *args: None)
    torch.manual_seed(3)
    full = adapter(wide_batch)
    assert int(fast.mask.sum()) > 50
    for name in ("xyz", "features", "mask"):
        assert torch.equal(getattr(fast, name), getattr(full, name)), name


def test_pixel_window_bounds_every_pixel_inside_the_box(synthetic_module):
    """Against the ray-caster's exact hit points: every pixel whose surface point lies in the box is inside
    the window, and the window is much smaller than the frame for a small box."""
    s = synthetic_module
    size = 96
    K = s.intrinsics(size)
    cam2world = s.look_at(eye=(0.5, -0.2, 0.45), target=(0.0, 0.0, 0.0))
    boxes = [(np.array([x, y, 0.03]), 0.03, s.CUBE_RGB) for x, y in [(0.05, 0.0), (-0.1, 0.08), (0.2, -0.2)]]
    _, depth, points = s.render(K, cam2world, size, boxes)
    box = (-0.12, 0.1, -0.05, 0.12, 0.005, 0.2)
    v0, v1, u0, u1 = geometry.box_pixel_window(
        torch.tensor(K, dtype=torch.float32)[None], torch.tensor(cam2world, dtype=torch.float32)[None], box, size, size
    )
    lo, hi = np.array(box[::2]), np.array(box[1::2])
    inside = (depth[..., 0] > 0) & np.all((points >= lo) & (points <= hi), axis=-1)
    rows, columns = np.nonzero(inside)
    assert len(rows) > 20
    assert rows.min() >= v0 and rows.max() < v1 and columns.min() >= u0 and columns.max() < u1
    assert (v1 - v0) * (u1 - u0) < 0.5 * size * size


def _brute_force_fps(points: np.ndarray, start: int, k: int) -> list[int]:
    chosen, dist = [start], np.full(len(points), np.inf)
    for _ in range(k - 1):
        dist = np.minimum(dist, ((points - points[chosen[-1]]) ** 2).sum(1))
        chosen.append(int(dist.argmax()))
    return chosen


def test_quick_fps_on_large_clouds_is_exact_farthest_point_sampling():
    """With start="any" (the plugin's point pipeline) clouds of QUICK_FPS_MIN_POINTS or more go through QuickFPS:
    from its start, every seed is the one a brute force picks (the documented difference: the start is the tree's
    first point, not the cloud's; start="first" is tested in test_geometry.py)."""
    g = torch.Generator().manual_seed(2)
    n = geometry.QUICK_FPS_MIN_POINTS + 700
    xyz = torch.rand(2, n + 50, 3, generator=g)
    mask = torch.ones(2, n + 50, dtype=torch.bool)
    mask[1, :50] = False  # padding at the front of the second cloud
    idx, seed_mask = geometry.farthest_point_sample(xyz, mask, 256, start="any")
    assert seed_mask.all()
    for b in range(2):
        valid = torch.nonzero(mask[b]).flatten()
        local = torch.searchsorted(valid, idx[b])
        assert mask[b, idx[b]].all()
        reference = _brute_force_fps(xyz[b, valid].double().numpy(), int(local[0]), 256)
        assert local.tolist() == reference
    again, _ = geometry.farthest_point_sample(xyz, mask, 256, start="any")
    assert torch.equal(idx, again)  # deterministic


@pytest.mark.parametrize("pipeline", ["plugin", "official"])
def test_point_tokens_at_inference_equal_the_grouped_path(wide_batch, pipeline):
    """The folded inference tokens (running max, BatchNorm folded) equal the training path's grouped tokens with
    the same frozen statistics, including clouds with fewer points than tokens (repeated slots)."""
    torch.manual_seed(0)
    encoder = make_encoder("pointnet", "pointcloud", output="tokens", dim=48, num_tokens=300, knn=8, pipeline=pipeline)
    for module in encoder.modules():
        if isinstance(module, torch.nn.BatchNorm1d):  # trained-looking statistics, some negative scales
            module.running_mean.normal_()
            module.running_var.uniform_(0.3, 3.0)
            module.weight.data.normal_()
            module.bias.data.normal_()
    cloud = ObservationAdapter(
        AdapterConfig("pointcloud", ["base_camera"], workspace=(-0.3, 0.3, -0.3, 0.3, 0.005, 0.5))
    ).eval()(wide_batch)
    assert (cloud.mask.sum(1) < 300).any() and (cloud.mask.sum(1) > 8).all()
    encoder.eval()
    with torch.no_grad():
        fast_tokens, fast_pos = encoder(cloud)
        encoder.train()  # the grouped path, with BatchNorm's running statistics as at inference
        for module in encoder.modules():
            if isinstance(module, torch.nn.BatchNorm1d):
                module.eval()
        tokens, pos = encoder(cloud)
    assert torch.equal(fast_pos, pos)
    torch.testing.assert_close(fast_tokens, tokens, rtol=1e-5, atol=1e-5)


def test_act_attention_skips_the_weights_only_at_inference(monkeypatch):
    from lerobot.configs.types import FeatureType, PolicyFeature

    from lerobot_obsbench.policies import ObsACTConfig
    from lerobot_obsbench.policies.obs_act.modeling_obs_act import ObsACTPolicy, WeightlessAttention
    from lerobot_obsbench.presets import preset_overrides

    torch.manual_seed(0)
    config = ObsACTConfig(
        device="cpu",
        obs_space="depth",
        input_features={
            "observation.depth.base_camera": PolicyFeature(FeatureType.STATE, (16, 16, 1)),
            "observation.state": PolicyFeature(FeatureType.STATE, (15,)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (7,))},
        **preset_overrides("tiny", "obs_act", "depth"),
    )
    policy = ObsACTPolicy(config)
    layers = [m for m in policy.model.modules() if isinstance(m, torch.nn.MultiheadAttention)]
    assert any(type(m) is WeightlessAttention for m in layers)
    calls = []
    original = torch.nn.MultiheadAttention.forward

    def spy(self, *args, **kwargs):
        calls.append(kwargs.get("need_weights", True))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(torch.nn.MultiheadAttention, "forward", spy)
    x = torch.randn(30, 2, 32)
    attention = next(m for m in layers if type(m) is WeightlessAttention)
    attention.eval()
    with torch.no_grad():
        fast = attention(x, x, value=x)[0]
        slow = original(attention, x, x, value=x)[0]
    attention.train()
    attention(x, x, value=x)
    assert calls == [False, True]
    torch.testing.assert_close(fast, slow, rtol=1e-5, atol=1e-6)


def test_step_timer_summary_and_warning():
    timer = StepTimer(fps=30)
    for _ in range(20):
        timer.record(0.020, 0.015)
    assert timer.summary()["late_steps"] == 0 and timer.warning(asynchronous=False) is None
    slow = StepTimer(fps=30)
    for _ in range(20):
        slow.record(0.080, 0.075)
    summary = slow.summary()
    assert summary["step_ms_median"] == 80.0 and summary["late_steps"] == 20 and summary["achieved_hz"] == 12.5
    message = slow.warning(asynchronous=False)
    assert "12.5 Hz, not 30" in message and "75.0 ms" in message and "--async_inference=true" in message
    assert "--async_inference" not in slow.warning(asynchronous=True)


def test_async_chunks_follow_the_newest_plan_without_blocking():
    """A policy four control steps slow: the loop never waits after the first chunk, each step takes its own
    index in the newest chunk, and a plan that runs out repeats its last action (counted)."""
    release = threading.Semaphore(0)  # one inference finishes per release: the test decides when, not a clock
    seen = []

    def infer(observation):
        seen.append(observation)
        release.acquire()
        return np.arange(observation, observation + 3, dtype=float)[:, None]  # chunk of 3 actions

    chunks = AsyncChunks(infer)
    release.release()
    assert chunks.action(0, 0)[0] == 0  # the first chunk is waited for
    actions = []
    for step in range(1, 6):  # the worker is busy with step 1's observation the whole time
        actions.append(float(chunks.action(step, step)[0]))
    assert actions == [1, 2, 2, 2, 2] and chunks.starved_steps == 3
    release.release()
    with chunks._lock:  # the worker notifies its condition when it stores a chunk
        chunks._lock.wait_for(lambda: chunks.chunks_done == 2)
    assert float(chunks.action(6, 6)[0]) == 3  # step 1's chunk holds steps 1..3: step 6 is past it
    assert seen[:2] == [0, 1]
    release.release()
    chunks.close()


def test_async_chunks_report_a_failing_policy():
    def infer(observation):
        raise ValueError("bad batch")

    chunks = AsyncChunks(infer)
    with pytest.raises(RuntimeError, match="asynchronous inference failed.*bad batch"):
        chunks.action(0, 0)
    chunks.close()
