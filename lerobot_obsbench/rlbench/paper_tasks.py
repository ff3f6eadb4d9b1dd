"""RLBench tasks with the location bounds the paper's code normalises positions with.

`LOCATION_BOUNDS` are the per-task (lo, hi) end-effector position bounds (metres, RLBench's world frame) of the
17 PerAct tasks that have them (PerAct's 18 without `place_cups`), at the precision the paper's code and
3D Diffuser Actor ship them. They were computed on keyframes; dense frames reach outside them (the start pose
sits about 1.47 m high), so normalised positions can exceed [-1, 1] — the paper's code uses them as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot_obsbench.errors import ObsBenchError

# task -> ((x, y, z) low, (x, y, z) high)
LOCATION_BOUNDS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "close_jar": (
        (-0.07010312378406525, -0.33692488074302673, 0.761122465133667),
        (0.525260329246521, 0.40034544467926025, 0.9308611154556274),
    ),
    "insert_onto_square_peg": (
        (-0.059705402702093124, -0.4115047752857208, 0.752871036529541),
        (0.4984903931617737, 0.37613850831985474, 0.9694802165031433),
    ),
    "light_bulb_in": (
        (0.001793097471818328, -0.3829135000705719, 0.8298617005348206),
        (0.5069130063056946, 0.39087292551994324, 1.1727949380874634),
    ),
    "meat_off_grill": (
        (-0.04940209910273552, -0.36016079783439636, 1.0511349439620972),
        (0.4341655671596527, 0.3369610607624054, 1.204141616821289),
    ),
    "open_drawer": (
        (0.10261330753564835, -0.06472617387771606, 0.9140162467956543),
        (0.3657068908214569, 0.4357367157936096, 1.2285298109054565),
    ),
    "place_shape_in_shape_sorter": (
        (-0.024208372458815575, -0.3702586591243744, 0.7619463205337524),
        (0.5094270706176758, 0.3993597626686096, 0.9559605121612549),
    ),
    "place_wine_at_rack_location": (
        (0.024810487404465675, -0.4179409146308899, 0.9237268567085266),
        (0.4800413250923157, 0.21476222574710846, 0.9975715279579163),
    ),
    "push_buttons": (
        (0.025005526840686798, -0.35272449254989624, 0.7704468369483948),
        (0.4750578701496124, 0.3518211841583252, 0.8459218144416809),
    ),
    "put_groceries_in_cupboard": (
        (-0.028621509671211243, -0.5157904028892517, 0.7696740627288818),
        (0.6081326603889465, 0.40632256865501404, 1.39157235622406),
    ),
    "put_item_in_drawer": (
        (0.07061523199081421, -0.22724466025829315, 0.91417396068573),
        (0.3534654974937439, 0.4783594608306885, 1.471603512763977),
    ),
    "put_money_in_safe": (
        (-0.05866488814353943, -0.2698633372783661, 0.788620114326477),
        (0.2451273500919342, 0.41097840666770935, 1.2644104957580566),
    ),
    "reach_and_drag": (
        (0.04688065126538277, -0.35880398750305176, 0.8532240390777588),
        (0.449143648147583, 0.3613968789577484, 0.9964548945426941),
    ),
    "slide_block_to_color_target": (
        (-0.018425436690449715, -0.3899671733379364, 0.7591497898101807),
        (0.5140739679336548, 0.37699267268180847, 0.779471755027771),
    ),
    "stack_blocks": (
        (-0.03135331720113754, -0.39724862575531006, 0.7737647294998169),
        (0.5072773694992065, 0.4063461422920227, 1.0446953773498535),
    ),
    "stack_cups": (
        (-0.0322563461959362, -0.3579411506652832, 0.8703824281692505),
        (0.4745761752128601, 0.413276731967926, 1.068880558013916),
    ),
    "sweep_to_dustpan_of_size": (
        (0.0757683739066124, -0.30235686898231506, 1.0714032649993896),
        (0.43045830726623535, 0.3017929792404175, 1.1362435817718506),
    ),
    "turn_tap": (
        (-0.01380503922700882, -0.1964014321565628, 0.884225606918335),
        (0.3865160644054413, 0.20687243342399597, 0.904780924320221),
    ),
}
# The paper's RLBench rows (Table 2 and the sample-efficiency study).
PAPER_TASKS = (
    "open_drawer",
    "sweep_to_dustpan_of_size",
    "meat_off_grill",
    "turn_tap",
    "reach_and_drag",
    "put_money_in_safe",
    "push_buttons",
    "close_jar",
    "place_wine_at_rack_location",
)


# How the paper's tables name them (Table 2 shortens some), for the report's side-by-side with a published table.
PAPER_ROWS = {
    "open_drawer": "open drawer",
    "sweep_to_dustpan_of_size": "sweep to",
    "meat_off_grill": "meat off grill",
    "turn_tap": "turn tap",
    "reach_and_drag": "reach and drag",
    "put_money_in_safe": "put money",
    "push_buttons": "push buttons",
    "close_jar": "close jar",
    "place_wine_at_rack_location": "place wine",
}
CAMERAS = ("front", "left_shoulder", "right_shoulder", "wrist", "overhead")
IMAGE_SIZE = 128  # PerAct's pre-generated data renders every camera at 128 x 128
# Point-cloud crop (world frame, metres): PerAct's scene bounds in x and y, z from just under the table top
# (0.76 m) to PerAct's 1.6 m, so the table's own points stay out of the cloud
WORKSPACE = (-0.3, 0.7, -0.5, 0.5, 0.76, 1.6)
# A grid names an RLBench task with this prefix (ManiSkill tasks keep their own ids)
GRID_PREFIX = "rlbench/"


def grid_task_name(task: str) -> str | None:
    """The RLBench task a grid's task entry names (`rlbench/open_drawer` -> open_drawer), None for ManiSkill."""
    return task.removeprefix(GRID_PREFIX) if task.startswith(GRID_PREFIX) else None


class RLBenchTaskError(ObsBenchError, ValueError):
    pass


@dataclass(frozen=True)
class RLBenchTask:
    name: str
    location_low: tuple[float, float, float]
    location_high: tuple[float, float, float]
    in_paper: bool


def rlbench_task(name: str) -> RLBenchTask:
    """The task's entry, or a clear error listing the known tasks."""
    if name not in LOCATION_BOUNDS:
        raise RLBenchTaskError(
            f"unknown RLBench task {name!r}: the importer knows the PerAct tasks with location bounds — paper: "
            f"{', '.join(PAPER_TASKS)}; others: {', '.join(t for t in LOCATION_BOUNDS if t not in PAPER_TASKS)}"
        )
    low, high = LOCATION_BOUNDS[name]
    return RLBenchTask(name, low, high, name in PAPER_TASKS)
