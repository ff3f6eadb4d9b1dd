"""One module per OBSBench task. Importing this package registers every task module in it (so adding a task
is adding one module here; see `lerobot_obsbench.envs.base_task`)."""

import importlib
import pkgutil

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")
