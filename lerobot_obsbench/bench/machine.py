"""The machine facts that decide a run's numbers, and the CPU kernel pin grids run under.

torch picks its CPU kernels by the processor (`torch.backends.cpu.get_cpu_capability()`: AVX2, AVX512, ...), and so
do MKL and oneDNN: the same run, trained on the same data with the same seeds, gives other weights on a machine
whose kernels differ, and its evaluation other episodes. A grid therefore runs every unit under one pinned
capability (`pin_environment`: ATen's `ATEN_CPU_CAPABILITY`, MKL's `MKL_ENABLE_INSTRUCTIONS`, oneDNN's
`ONEDNN_MAX_CPU_ISA`), AVX2 by default, the one every x86-64 machine of the last decade has, and every train and
eval record carries the facts of the process that made it (`machine_facts`), so a report can say when it pools runs
made under different ones.

Run as a script (`python machine.py`), it prints this process's facts as JSON without importing the plugin: a
training unit asks it for the facts of the lerobot-train it starts, under the same environment.
"""

from __future__ import annotations

import functools
import json
import os
import platform
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

# torch's capabilities on x86-64, lowest first (`torch.backends.cpu.get_cpu_capability()` names)
X86_CAPABILITIES = ("DEFAULT", "AVX2", "AVX512")


@dataclass(frozen=True)
class KernelPin:
    """One CPU kernel capability as each library that dispatches on the processor spells it."""

    aten: str  # ATEN_CPU_CAPABILITY (torch's own kernels)
    mkl: str  # MKL_ENABLE_INSTRUCTIONS (BLAS: matrix products)
    onednn: str  # ONEDNN_MAX_CPU_ISA (convolutions)

    def environment(self) -> dict[str, str]:
        return {
            "ATEN_CPU_CAPABILITY": self.aten,
            "MKL_ENABLE_INSTRUCTIONS": self.mkl,
            "ONEDNN_MAX_CPU_ISA": self.onednn,
        }


PINS = {
    "default": KernelPin("default", "SSE4_2", "SSE41"),
    "avx2": KernelPin("avx2", "AVX2", "AVX2"),
    "avx512": KernelPin("avx512", "AVX512", "AVX512_CORE"),
}
PIN_VARIABLES = tuple(PINS["avx2"].environment())
NATIVE = "native"  # no pin: each library picks this machine's best kernels
CAPABILITY_CHOICES = (*PINS, NATIVE)
DEFAULT_CAPABILITY = "avx2"


class CapabilityError(ValueError):
    """A kernel pin this machine cannot run (the runner raises it as the plugin's one-line usage error: this module
    imports nothing of the plugin, so that it runs as a script in a fresh interpreter)."""


def default_capability() -> str:
    """The pin grids run under by default: AVX2 on x86-64; elsewhere (ARM, POWER) torch has other kernels, no pin."""
    return DEFAULT_CAPABILITY if platform.machine().lower() in ("x86_64", "amd64") else NATIVE


def pin_environment(capability: str) -> dict[str, str]:
    """The environment variables that pin `capability` ({} for `native`); refuses a capability this machine's
    processor lacks (its kernels would stop on an illegal instruction), naming the ones it has."""
    if capability not in CAPABILITY_CHOICES:
        raise CapabilityError(f"--cpu-capability must be one of {', '.join(CAPABILITY_CHOICES)}; got {capability!r}")
    if capability == NATIVE:
        return {}
    native = native_capability()
    if native not in X86_CAPABILITIES:
        raise CapabilityError(
            f"--cpu-capability {capability} pins x86-64 kernels; this machine's torch runs {native} kernels: use "
            f"--cpu-capability {NATIVE}"
        )
    if X86_CAPABILITIES.index(capability.upper()) > X86_CAPABILITIES.index(native):
        usable = [c.lower() for c in X86_CAPABILITIES[: X86_CAPABILITIES.index(native) + 1]]
        raise CapabilityError(
            f"this machine's processor has no {capability.upper()} kernels (torch's best here: {native}): use "
            f"--cpu-capability {' or '.join([*usable, NATIVE])} (runs made under another capability than "
            "the published ones' may give other numbers)"
        )
    return PINS[capability].environment()


@functools.lru_cache(maxsize=1)
def native_capability() -> str:
    """torch's capability on this machine with nothing pinned (asked of a fresh interpreter: this process may
    have read a pin from its environment already)."""
    env = {k: v for k, v in os.environ.items() if k not in PIN_VARIABLES}
    return facts_of_process(env)["cpu_capability"]


def facts_of_process(env: dict[str, str]) -> dict:
    """`machine_facts()` of a new Python process started with `env` (as lerobot-train is)."""
    done = subprocess.run(
        [sys.executable, str(Path(__file__))], env=env, capture_output=True, text=True, stdin=subprocess.DEVNULL
    )
    if done.returncode != 0:
        raise RuntimeError(f"reading the machine's facts failed: {done.stderr.strip()[-500:]}")
    return json.loads(done.stdout)


def machine_facts() -> dict:
    """What decides this process's numbers besides the run itself: torch's CPU capability, the processor, the
    library builds (torch, MKL, oneDNN), the kernel pins in effect, torch's thread count and the GPU."""
    import torch

    build = torch.__config__.show()
    facts = {
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "cpu": cpu_model(),
        "arch": platform.machine(),
        "torch": f"{torch.__version__} ({(torch.version.git_version or '')[:12]})",
        "mkl": _build_line(build, r"Math Kernel Library Version (\S+)"),
        "onednn": _build_line(build, r"MKL-DNN (v\S+)"),
        "pins": {name: os.environ[name] for name in PIN_VARIABLES if name in os.environ},
        "threads": torch.get_num_threads(),
    }
    if torch.cuda.is_available():
        facts["gpu"] = torch.cuda.get_device_name(0)
    return facts


def _build_line(build: str, pattern: str) -> str | None:
    found = re.search(pattern, build)
    return found.group(1) if found else None


def cpu_model() -> str:
    """The processor's model name (Linux: /proc/cpuinfo), else what `platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def fingerprint(facts: dict | None) -> str:
    """One line naming the facts that decide a record's numbers; "not recorded" for records written before
    records carried them."""
    if not facts:
        return "not recorded"
    parts = [facts["cpu_capability"], facts["cpu"], f"torch {facts['torch']}"]
    parts += [f"MKL {facts['mkl']}"] if facts.get("mkl") else []
    parts += [f"oneDNN {facts['onednn']}"] if facts.get("onednn") else []
    parts += [f"{facts['threads']} thread{'s' if facts['threads'] != 1 else ''}"]
    parts += [facts["gpu"]] if facts.get("gpu") else []
    return ", ".join(parts)


if __name__ == "__main__":
    print(json.dumps(machine_facts()))
