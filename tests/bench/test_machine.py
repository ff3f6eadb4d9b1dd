"""The CPU kernel pin grids run under, and the machine facts every record carries (bench/machine.py): a pin takes
effect in the processes the runner starts, a pin this processor cannot run is refused in one line before anything
runs, and the facts name the kernels, the processor and the library builds."""

from __future__ import annotations

import os
import platform

import pytest

from lerobot_obsbench.bench import machine
from lerobot_obsbench.cli import main

x86 = pytest.mark.skipif(platform.machine() != "x86_64", reason="torch's kernel pins are x86-64's")


@x86
def test_a_pin_takes_effect_in_a_new_process_and_its_facts_name_it():
    native = machine.native_capability()
    unpinned = {k: v for k, v in os.environ.items() if k not in machine.PIN_VARIABLES}
    facts = machine.facts_of_process({**unpinned, **machine.pin_environment("default")})
    assert facts["cpu_capability"] == "DEFAULT" != native  # every x86-64 machine torch runs on has AVX2 or more
    assert facts["pins"] == {
        "ATEN_CPU_CAPABILITY": "default",
        "MKL_ENABLE_INSTRUCTIONS": "SSE4_2",
        "ONEDNN_MAX_CPU_ISA": "SSE41",
    }
    own = machine.facts_of_process(unpinned)
    assert own["cpu_capability"] == native and own["pins"] == {}
    assert facts["cpu"] == machine.cpu_model() and facts["torch"].startswith(__import__("torch").__version__)
    assert facts["threads"] >= 1 and "MKL" in machine.fingerprint(facts) and "DEFAULT" in machine.fingerprint(facts)
    assert machine.fingerprint(None) == "not recorded"


@pytest.mark.parametrize(
    ("native", "asked", "refusal"),
    [
        (
            "AVX2",
            "avx512",
            "no AVX512 kernels (torch's best here: AVX2): use --cpu-capability default or avx2 or native",
        ),
        ("DEFAULT", "avx2", "no AVX2 kernels (torch's best here: DEFAULT): use --cpu-capability default or native"),
        (
            "SVE256",
            "avx2",
            "pins x86-64 kernels; this machine's torch runs SVE256 kernels: use --cpu-capability native",
        ),
    ],
)
def test_a_pin_the_processor_cannot_run_is_refused_naming_the_ones_it_can(monkeypatch, native, asked, refusal):
    monkeypatch.setattr(machine, "native_capability", lambda: native)
    with pytest.raises(machine.CapabilityError, match=refusal.replace("(", r"\(").replace(")", r"\)")):
        machine.pin_environment(asked)
    assert machine.pin_environment(machine.NATIVE) == {}


def test_the_runner_refuses_an_impossible_pin_in_one_line_before_any_work(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(machine, "native_capability", lambda: "AVX2")
    grid = tmp_path / "g.yaml"
    grid.write_text("tasks: [PushCube-v1]\nobs_spaces: [none]\nsteps: 5\npreset: tiny\n")
    assert main(["run", str(grid), "--out", str(tmp_path / "out"), "--cpu-capability", "avx512"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no AVX512 kernels" in err and not (tmp_path / "out").exists()


@x86
def test_the_dry_run_names_the_pin_it_runs_under(tmp_path, capsys):
    grid = tmp_path / "g.yaml"
    grid.write_text("tasks: [PushCube-v1]\nobs_spaces: [none]\nsteps: 5\npreset: tiny\n")
    assert main(["run", str(grid), "--out", str(tmp_path / "out"), "--dry-run"]) == 0
    assert (
        "CPU kernels pinned to avx2 (ATEN_CPU_CAPABILITY=avx2, MKL_ENABLE_INSTRUCTIONS=AVX2" in capsys.readouterr().out
    )
    assert main(["run", str(grid), "--out", str(tmp_path / "out"), "--dry-run", "--cpu-capability", "native"]) == 0
    assert f"CPU kernels: this machine's own ({machine.native_capability()}), not pinned" in capsys.readouterr().out
