"""Rows of the bad-input table (`tests/commands/test_bad_inputs.py`) for grid: each `(setup, fragments)`, where
`setup(root) -> argv` builds its inputs in a fresh folder and `fragments` are what the one error line must hold."""

from __future__ import annotations

from pathlib import Path


def _grid(root: Path, text: str) -> list[str]:
    """The dry run of a one-space grid with `text` added."""
    from tests.commands.test_bad_inputs import _grid  # the table's grid writer (imported here late: it imports us)

    return _grid(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\n" + text)


def grid_with_a_recipe_written_twice(root: Path) -> list[str]:
    """Used to make two methods of one recipe, training the same thing twice under two run ids."""
    return _grid(root, 'augmentations: {rgb: [random_shift, " random_shift"]}\n')


def grid_with_a_recipe_in_two_orders_that_train_alike(root: Path) -> list[str]:
    """Image and colour transforms apply at their own points whatever the order of their names."""
    return _grid(root, "augmentations: {rgb: [random_shift+colour_jitter, colour_jitter+random_shift]}\n")


def grid_with_a_seed_written_as_a_whole_and_a_decimal(root: Path) -> list[str]:
    """Used to be refused as not a whole number, which the project's rule for numbers says 1.0 is."""
    return _grid(root, "seeds: [1, 1.0]\n")


def _written(root: Path, text: str) -> list[str]:
    """The dry run of the grid `text`, written whole."""
    from tests.commands.test_bad_inputs import _grid as write  # (imported here late: it imports us)

    return write(root, text)


def grid_with_fractional_steps(root: Path) -> list[str]:
    """Used to pass as a run of its own (budget 2.5) training what steps: 2 trains."""
    return _written(root, "tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 2.5\n")


def grid_with_a_learning_rate_yaml_reads_as_text(root: Path) -> list[str]:
    """YAML reads 1e-3 (no decimal point) as a string: the refusal used to say only "not a number"."""
    return _grid(root, "learning_rates: [1e-3]\n")


def grid_with_no_camera_for_a_seeing_space(root: Path) -> list[str]:
    """Used to pass the dry run, record demonstrations with no camera and fail at the space's training."""
    return _grid(root, "cameras: []\n")


def grid_with_an_unknown_perturbation(root: Path) -> list[str]:
    return _grid(root, "perturbations: [dusk:1]\n")


def grid_with_depth_noise_beyond_its_levels(root: Path) -> list[str]:
    return _grid(root, "perturbations: [depth_noise:6]\n")


def grid_with_depth_noise_and_no_space_built_from_depth(root: Path) -> list[str]:
    return _grid(root, "perturbations: [depth_noise:1]\n")


def grid_with_a_maniskill_task_in_lower_case(root: Path) -> list[str]:
    """Reads as a Meta-World name: used to be offered Meta-World look-alikes only."""
    return _written(root, "tasks: [pushcube-v1]\nobs_spaces: [rgb]\nsteps: 5\n")


def metaworld_grid_with_ray_traced_noise(root: Path) -> list[str]:
    return _written(root, "tasks: [reach-v3]\nobs_spaces: [rgb]\nsteps: 5\nperturbations: [noise:16]\n")


ROWS: list = [
    (grid_with_a_recipe_written_twice, ['augmentations.rgb lists "random_shift" more than once', "list it once"]),
    (
        grid_with_a_recipe_in_two_orders_that_train_alike,
        ['augmentations.rgb lists "random_shift+colour_jitter" more than once'],
    ),
    (grid_with_a_seed_written_as_a_whole_and_a_decimal, ["seeds lists 1 more than once"]),
    (grid_with_fractional_steps, ["steps must be a whole number >= 1; got 2.5"]),
    (grid_with_a_learning_rate_yaml_reads_as_text, ["learning_rates[0] must be a finite number > 0", "write 1.0e-3"]),
    (grid_with_no_camera_for_a_seeing_space, ["cameras is empty, and obs_spaces ['rgb'] read a camera"]),
    (grid_with_an_unknown_perturbation, ["unknown perturbation 'dusk:1'; write one of camera_yaw:DEG"]),
    (grid_with_depth_noise_beyond_its_levels, ["depth_noise takes a level in (0, 4]"]),
    (grid_with_depth_noise_and_no_space_built_from_depth, ["depth_noise:1 changes only what spaces reading depth see"]),
    (metaworld_grid_with_ray_traced_noise, ["Meta-World tasks do not support noise perturbations"]),
    (grid_with_a_maniskill_task_in_lower_case, ["unknown task 'pushcube-v1'", "did you mean PushCube-v1?"]),
]
