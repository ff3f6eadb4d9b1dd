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


ROWS: list = [
    (grid_with_a_recipe_written_twice, ['augmentations.rgb lists "random_shift" more than once', "list it once"]),
    (
        grid_with_a_recipe_in_two_orders_that_train_alike,
        ['augmentations.rgb lists "random_shift+colour_jitter" more than once'],
    ),
    (grid_with_a_seed_written_as_a_whole_and_a_decimal, ["seeds lists 1 more than once"]),
]
