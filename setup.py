"""The packages to build, beside pyproject.toml's metadata: what setuptools finds under lerobot_obsbench* and
lerobot_policy_obsbench*, plus the repository's top-level `configs/` (the preset grids), shipped inside the wheel
as `lerobot_obsbench/configs` so an installed plugin finds them by name (`bench.package_data`)."""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["lerobot_obsbench*", "lerobot_policy_obsbench*"]), "lerobot_obsbench.configs"],
    package_dir={"lerobot_obsbench.configs": "configs"},
)
