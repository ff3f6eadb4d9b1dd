"""What a Meta-World frame costs on this machine: MuJoCo's physics step against rendering one camera's colour
(the env's: the scene's lighting from a 1024-pixel shadow map; from the scene's own 4096-pixel map, as Meta-World and
LeRobot draw it; without shadows; without shadows and reflections) and depth, at each image size, timed
interleaved (one of each in turn, so whatever else the machine does falls on all alike) after untimed warm-up
frames. The frames are `MetaWorldEnv`'s own renders (the same camera and conversion to the schema's uint16
millimetres); the colour variants differ only in the scene flags or the shadow map. How far the env's colour frames
are from the scene map's: the mean and 99th percentile of the absolute difference (grey levels of 255).

    .venv/bin/python -m benchmarks.bench_metaworld_render [--task drawer-open-v3] [--camera corner2]
        [--sizes 64 128] [--repeats 30] [--out FILE]

Writes benchmarks/results/metaworld_render.json: per size, the median milliseconds of each variant, the physics
step's, and the colour difference.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from benchmarks.common import write
from lerobot_obsbench.envs.metaworld.env import MetaWorldEnv
from lerobot_obsbench.envs.metaworld.rendering import choose_gl, open_renderer
from lerobot_obsbench.numeric import number_argument

SCENE_SHADOW_MAP_SIZE = 4096  # the Sawyer scene's (MuJoCo's default), which Meta-World and LeRobot render with


def _milliseconds(step) -> float:
    start = time.perf_counter()
    step()
    return (time.perf_counter() - start) * 1000


def size_row(task: str, camera: str, size: int, repeats: int, warmup: int) -> dict:
    import mujoco

    env = MetaWorldEnv(task, cameras=[camera], image_size=size)
    env.reset(seed=0)
    flags = env._renderer.scene.flags
    own = env._renderer
    env._env.model.vis.quality.shadowsize = SCENE_SHADOW_MAP_SIZE
    scene_map = open_renderer(env._env.model, size, size)

    def colour(shadow: bool, reflection: bool):
        def render():
            flags[mujoco.mjtRndFlag.mjRND_SHADOW] = shadow
            flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = reflection
            return env._render(camera, colour=True, depth=False)[0]

        return render

    def with_scene_map():
        env._renderer = scene_map
        try:
            return env._render(camera, colour=True, depth=False)[0]
        finally:
            env._renderer = own

    variants = {
        "colour": colour(True, True),
        "colour_scene_shadow_map": with_scene_map,
        "colour_no_shadows": colour(False, True),
        "colour_no_shadows_no_reflections": colour(False, False),
        "depth": lambda: env._render(camera, colour=False, depth=True),
    }
    for _ in range(warmup):
        for render in variants.values():
            render()
    times = {name: [] for name in variants}
    for _ in range(repeats):
        for name, render in variants.items():
            times[name].append(_milliseconds(render))
    flags[mujoco.mjtRndFlag.mjRND_SHADOW] = flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = True
    difference = np.abs(variants["colour"]().astype(float) - with_scene_map().astype(float))
    scene_map.close()
    env.close()
    physics = MetaWorldEnv(task, cameras=[])
    physics.reset(seed=0)
    rng = np.random.default_rng(0)
    steps = [_milliseconds(lambda: physics._env.step(rng.uniform(-1, 1, 4))) for _ in range(repeats * 10)]
    physics.close()
    row = {
        "image_size": size,
        "median_ms": {name: round(statistics.median(t), 2) for name, t in times.items()},
        "physics_step_ms": round(statistics.median(steps), 3),
        "colour_vs_scene_shadow_map": {
            "mean_abs": round(float(difference.mean()), 3),
            "p99_abs": float(np.percentile(difference, 99)),
        },
        "repeats": repeats,
        "warmup": warmup,
    }
    print(f"{size}px: {row['median_ms']}, physics step {row['physics_step_ms']} ms", flush=True)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="drawer-open-v3")
    parser.add_argument("--camera", default="corner2")
    parser.add_argument("--sizes", type=number_argument(whole=True, minimum=32), nargs="+", default=[64, 128])
    parser.add_argument("--repeats", type=number_argument(whole=True, minimum=1), default=30)
    parser.add_argument("--warmup", type=number_argument(whole=True, minimum=0), default=5)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    choose_gl()
    rows = [size_row(args.task, args.camera, size, args.repeats, args.warmup) for size in args.sizes]
    write("metaworld_render", {"task": args.task, "camera": args.camera, "rows": rows}, args.out)


if __name__ == "__main__":
    main()
