"""Report math (competition ranking, Mean S.R. / Mean Rank, pooled Wilson intervals), the published-table
reader, the results store's handling of corrupted lines, and the rendered Markdown / HTML / PNG / JSON."""

from __future__ import annotations

import json

import pytest

from lerobot_obsbench.bench.report import (
    ReportError,
    build_report,
    cells_by_task,
    competition_ranks,
    read_published,
    summarize,
    summary_json,
    write_report,
)
from lerobot_obsbench.bench.results import ResultsFormatError, append_result, by_kind, read_results
from lerobot_obsbench.cli import main
from lerobot_obsbench.stats import wilson_interval


def test_competition_ranking_1224():
    assert competition_ranks({"a": 0.9, "b": 0.5, "c": 0.5, "d": 0.1}) == {"a": 1, "b": 2, "c": 2, "d": 4}
    assert competition_ranks({"a": 0.3, "b": 0.3, "c": 0.3}) == {"a": 1, "b": 1, "c": 1}


def test_mean_sr_and_mean_rank_by_hand():
    table = {
        "t1": {"A": 0.80, "B": 0.60, "C": 0.60},
        "t2": {"A": 0.10, "B": 0.30, "C": 0.20},
        "t3": {"A": 0.00, "B": 0.00, "C": 0.50},
    }
    summary = summarize(table)
    # A: ranks 1, 3, 2 ; B: 2, 1, 2 ; C: 2, 2, 1
    assert summary["A"]["mean_rank"] == pytest.approx(2.0)
    assert summary["B"]["mean_rank"] == pytest.approx(5 / 3)
    assert summary["C"]["mean_rank"] == pytest.approx(5 / 3)
    assert summary["A"]["mean_sr"] == pytest.approx(0.3)
    assert summary["C"]["mean_sr"] == pytest.approx(1.3 / 3)


def test_published_table_csv(tmp_path):
    path = tmp_path / "table.csv"
    path.write_text("task,ResNet50,PointNet\nPickCube,0.10,0.30\nStackCube,0.05,\n")
    table = read_published(path)
    assert table == {"PickCube": {"ResNet50": 0.10, "PointNet": 0.30}, "StackCube": {"ResNet50": 0.05}}
    summary = summarize(table)
    assert summary["PointNet"]["tasks"] == 1 and summary["ResNet50"]["mean_sr"] == pytest.approx(0.075)
    for body, words in (
        ("task,A\nt1,abc\n", ["table.csv:2", "'abc'"]),
        ("task,A\nt1,45\n", [":2", "[0, 1]"]),
        ("task,A,B\nt1,0.1\n", [":2", "2 cells"]),
    ):
        path.write_text(body)
        with pytest.raises(ReportError) as err:
            read_published(path)
        for word in words:
            assert word in str(err.value)


def record(run_id, task, space, successes, episodes=10, seed=0, demos=10, lr=1e-4, evaluations=None):
    config = {
        "task": task,
        "obs_space": space,
        "encoder": "e",
        "policy": "obs_act",
        "seed": seed,
        "lr": lr,
        "demos": demos,
        "preset": "cpu",
        "budget_unit": "steps",
        "budget": 5,
        "image_size": 64,
        "policy_overrides": {},
    }
    base = {"successes": successes, "episodes": episodes, "success_rate": successes / episodes}
    return {
        "run_id": run_id,
        "config": config,
        "method": f"obs_act/{space}/e",
        "task": task,
        "evaluations": {"none": base, **(evaluations or {})},
    }


# the machine facts every record of `stored` carries unless its view names others (`machine.machine_facts`)
MACHINE = {"cpu_capability": "AVX2", "cpu": "a CPU", "torch": "2.11.0 (70d99e998b49)", "threads": 1, "pins": {}}


def stored(*views) -> list[dict]:
    """The results store's train and eval records (what `obsbench run` writes) of run views."""
    out = []
    for v in views:
        machine = v.get("machine", MACHINE)
        out.append(
            {
                "kind": "train",
                "run_id": v["run_id"],
                "config": v["config"],
                "method": v["method"],
                "task": v["task"],
                "checkpoint": f"runs/{v['run_id']}/last",
                **({"machine": machine} if machine is not None else {}),
                **({"diagnostics": v["diagnostics"]} if "diagnostics" in v else {}),
                **{k: v[k] for k in ("resumed_from", "resumed_exactly") if k in v},
            }
        )
        for name, summary in v["evaluations"].items():
            out.append(
                {
                    "kind": "eval",
                    "eval_id": f"{v['run_id']}:{name}",
                    "run_id": v["run_id"],
                    "checkpoint": "last",
                    "split": "test",
                    "perturbation": name,
                    **({"machine": machine} if machine is not None else {}),
                    **summary,
                }
            )
    return out


def test_the_report_says_when_it_pools_runs_made_under_other_machine_facts_or_resumed_inexactly():
    """Runs made under one set of facts pool silently; a run made under other CPU kernels is named with the count of
    each; records without facts (written before records had them) are said to be unrecorded; a run resumed by
    LeRobot's own resume (before the plugin's fix) is named, one resumed exactly is not."""
    same = [record(f"r{seed}", "T", "rgb", 5, seed=seed) for seed in range(3)]
    assert build_report(stored(*same))["warnings"] == []
    other = {**record("r3", "T", "rgb", 5, seed=3), "machine": {**MACHINE, "cpu_capability": "AVX512"}}
    report = build_report(stored(*same, other))
    (warning,) = report["warnings"]
    assert "3 run(s) under AVX2, a CPU" in warning and "1 run(s) under AVX512, a CPU" in warning
    assert sorted(report["checks"]["machines"].values()) == [1, 3]
    unrecorded = [{**r, "machine": None} for r in same]
    assert "were not recorded" in build_report(stored(*unrecorded))["warnings"][0]
    resumed = [
        {**same[0], "resumed_from": 3000},
        {**same[1], "resumed_from": 2000, "resumed_exactly": True},
        same[2],
    ]
    report = build_report(stored(*resumed))
    (warning,) = report["warnings"]
    assert "1 run(s) were resumed" in warning and "seed 0 (at step 3000)" in warning and "seed 1" not in warning
    assert report["checks"]["inexact_resumes"] == ["T obs_act/rgb/e seed 0 (at step 3000)"]


def test_a_run_trained_again_replaces_its_earlier_training_record_and_keeps_its_evaluations(tmp_path):
    path = tmp_path / "results.jsonl"
    first, again = stored(record("r1", "T", "rgb", 3))
    for line in (first, again, {**first, "checkpoint": "elsewhere"}, {**first, "checkpoint": "new", "retrained": True}):
        append_result(path, line)
    warnings = []
    records = read_results(path, warn=warnings.append)
    (train,) = by_kind(records, "train")
    assert train["checkpoint"] == "new" and len(by_kind(records, "eval")) == 1
    assert len(warnings) == 1 and "1 repeated record(s) skipped (lines 3:" in warnings[0]  # a repeat, not a retrain


def test_results_store_reports_corrupted_lines_and_never_merges_lines(tmp_path):
    path = tmp_path / "results.jsonl"
    train_a, eval_a = stored(record("a", "T", "rgb", 3))
    append_result(path, train_a)
    with open(path, "a") as f:
        f.write('{"kind": "eval", "run_id": "a", "config": {')  # a kill in the middle of a write
    append_result(path, eval_a)
    with open(path, "a") as f:
        f.write('{"kind": "eval", "no_id": 1}\n')
    warnings = []
    records = read_results(path, warn=warnings.append)
    assert records == [train_a, eval_a]
    assert len(warnings) == 2
    assert "results.jsonl:2: corrupted results line skipped" in warnings[0]
    assert "results.jsonl:4" in warnings[1] and "eval_id" in warnings[1]


def test_results_of_version_0_1_are_refused_with_the_conversion_command(tmp_path, capsys):
    """0.1 wrote one record per run with its evaluations; `obsbench convert-results` keeps every number."""
    path = tmp_path / "results.jsonl"
    old = record(
        "0123456789abcdef", "PushCube-v1", "rgb", 3, evaluations={"light:0.03": {"successes": 1, "episodes": 10}}
    )
    old["config"] = {
        **{k: v for k, v in old["config"].items() if k not in ("budget_unit", "budget")},
        "steps": 5,
        "epochs": None,
        "batch_size": 4,
        "cameras": ["base_camera"],
        "control_mode": "pd_ee_delta_pose",
        "eval_episodes": 10,
        "perturbations": ["light:0.03"],
    }
    old.update(checkpoint="/runs/0123/train/checkpoints/last/pretrained_model", train_steps=5)
    path.write_text(json.dumps(old) + "\n")
    with pytest.raises(ResultsFormatError, match="lerobot-obsbench 0.1.*obsbench convert-results"):
        read_results(path)
    assert main(["report", str(path)]) == 2
    assert "obsbench convert-results" in capsys.readouterr().err
    assert main(["convert-results", str(path)]) == 0
    records = read_results(path)
    (train,) = by_kind(records, "train")
    assert train["config"]["budget_unit"] == "steps" and train["config"]["budget"] == 5
    assert train["checkpoint"] == old["checkpoint"] and train["upgraded_from"] == old["run_id"]
    evals = {r["perturbation"]: r for r in by_kind(records, "eval")}
    assert (evals["none"]["successes"], evals["light:0.03"]["successes"]) == (3, 1)
    assert all(r["run_id"] == train["run_id"] and r["checkpoint"] == "last" for r in evals.values())
    assert (tmp_path / "results.jsonl.v1").read_text() == json.dumps(old) + "\n"
    assert main(["report", str(path)]) == 0


def test_training_seeds_pool_their_episodes_and_widen_the_interval():
    """One seed: the Wilson interval of its episodes. Several: the pooled rate, with an interval over seeds and
    episodes, wider than the pooled Wilson one when the seeds disagree."""
    records = [
        record("a", "T", "rgb", 2, seed=0),
        record("b", "T", "rgb", 8, seed=1),
        record("c", "T", "pointcloud", 9, seed=0),
    ]
    cells = cells_by_task(records)
    rgb, pointcloud = cells["T"]["obs_act/rgb/e"], cells["T"]["obs_act/pointcloud/e"]
    assert (rgb.runs, rgb.successes, rgb.episodes, rgb.seeds, rgb.rate) == (((2, 10), (8, 10)), 10, 20, 2, 0.5)
    assert pointcloud.ci95 == wilson_interval(9, 10)
    lo, hi = rgb.ci95
    pooled_lo, pooled_hi = wilson_interval(10, 20)
    assert lo < pooled_lo and hi > pooled_hi  # the two seeds disagree: training variance widens it


def test_a_method_that_never_or_always_succeeds_has_its_rate_inside_its_interval(tmp_path):
    """Seeds at 0/n (or n/n) all: the interval over seeds and episodes ends at 0 (or 1), as Jeffreys' does, and
    the report draws such a grid (a task nothing learns)."""
    records = [record(f"n{s}", "T", "rgb", 0, seed=s) for s in range(3)]
    records += [record(f"a{s}", "T", "pointcloud", 10, seed=s) for s in range(3)]
    cells = cells_by_task(records)["T"]
    never, always = cells["obs_act/rgb/e"], cells["obs_act/pointcloud/e"]
    assert never.ci95[0] == 0.0 < never.ci95[1] < 0.5 and 0.5 < always.ci95[0] < always.ci95[1] == 1.0
    paths = write_report(build_report(stored(*records)), tmp_path / "rep")
    assert (tmp_path / "rep" / "success_by_task.png").read_bytes()[:4] == b"\x89PNG"
    assert "0.00 [0.00, " in paths["markdown"].read_text()


def test_varying_learning_rates_become_separate_columns():
    records = [record("a", "T", "rgb", 3, lr=1e-4), record("b", "T", "rgb", 5, lr=1e-3)]
    assert set(cells_by_task(records)["T"]) == {"obs_act/rgb/e lr=0.0001", "obs_act/rgb/e lr=0.001"}


def test_report_files(tmp_path):
    light = {"light:0.03": {"successes": 1, "episodes": 10}}
    records = [
        record("a", "T1", "rgb", 2, evaluations=light),
        record("b", "T1", "pointcloud", 8, evaluations=light),
        record("c", "T2", "rgb", 6),
        record("d", "T2", "pointcloud", 6),
        record("e", "T1", "rgb", 1, demos=5),
        record("f", "T1", "pointcloud", 4, demos=5),
    ]
    published = tmp_path / "paper.csv"
    published.write_text("task,ResNet50\nT1,0.25\nT9,0.5\n")
    report = build_report(stored(*records), read_published(published), published_name="paper")
    paths = write_report(report, tmp_path / "rep")
    md = paths["markdown"].read_text()
    assert "**0.80 [" in md and "<u>0.20 [" in md  # T1: pointcloud best (bold), rgb second (underlined)
    assert "| Mean S.R. | **0.70** | <u>0.40</u> |" in md
    assert "| Mean Rank | **1.00** | <u>1.50</u> |" in md  # T2 tie: both rank 1
    assert "Side by side on the shared rows (T1)" in md and "ResNet50 (paper)" in md
    page = paths["html"].read_text()
    assert page.count("data:image/png;base64,") == 4  # bars, aggregates, light robustness, sample efficiency
    assert "<b>0.80" in page
    # no blind control: no probability-of-improvement plot; one seed per column: said under the title
    assert "probability_of_improvement.png" not in md and "> **Note:** One training seed behind" in md
    for name in ("success_by_task.png", "aggregates.png", "robustness_light.png", "sample_efficiency.png"):
        assert (tmp_path / "rep" / name).read_bytes()[:4] == b"\x89PNG"
    summary = summary_json(report)
    # under light:0.03 rgb keeps 1/10 of its 2/10 (a half), pointcloud 1/10 of 8/10; T2 was not perturbed
    kept = summary["checks"]["robustness"]["light:0.03"]
    assert kept["T1"]["obs_act/rgb/e"][0] == pytest.approx(0.5) and "T2" not in kept
    assert kept["all tasks"]["obs_act/pointcloud/e"][0] == pytest.approx(0.125)
    assert "Robustness: the share of the unperturbed success kept" in md
    # 5 and 10 demonstrations on T1 only, so the mean over tasks is T1's
    efficiency = summary["checks"]["sample_efficiency"]
    assert efficiency["all tasks"]["obs_act/rgb/e"]["5"][0] == pytest.approx(0.1)
    assert efficiency["T1"]["obs_act/pointcloud/e"]["10"][0] == pytest.approx(0.8)
    assert summary["results"]["obs_act/pointcloud/e"] == {"mean_sr": 0.7, "mean_rank": 1.0, "tasks": 2}
    assert summary["published"]["ResNet50"]["mean_sr"] == pytest.approx(0.375)


def test_robustness_is_the_share_of_unperturbed_success_kept_with_intervals_over_training_seeds():
    """Three training seeds per column on two tasks: rgb keeps 12/30 of 24/30 on T1 and 0 of 15/30 on T2 under
    camera_yaw:10 (a quarter over the two); pointcloud keeps all of its; a column that never succeeds unperturbed
    has no share; blind is not evaluated under the perturbation and has no row."""
    yaw = "camera_yaw:10"
    outcomes = {  # task, space: (nominal per seed, perturbed per seed)
        ("T1", "rgb"): ((8, 8, 8), (4, 4, 4)),
        ("T2", "rgb"): ((5, 5, 5), (0, 0, 0)),
        ("T1", "pointcloud"): ((7, 8, 9), (7, 8, 9)),
        ("T2", "pointcloud"): ((6, 6, 6), (6, 6, 6)),
        ("T1", "depth"): ((0, 0, 0), (0, 0, 1)),
    }
    records = [
        record(
            f"{task}{space}{seed}",
            task,
            space,
            nominal[seed],
            seed=seed,
            evaluations={yaw: {"successes": perturbed[seed], "episodes": 10}},
        )
        for (task, space), (nominal, perturbed) in outcomes.items()
        for seed in range(3)
    ] + [record(f"blind{seed}", "T1", "none", 2, seed=seed) for seed in range(3)]
    found = build_report(stored(*records))["checks"]["robustness"][yaw]
    point, low, high = found["all tasks"]["obs_act/rgb/e"]
    assert point == pytest.approx(0.25) and low < 0.25 < high and high < 0.5
    assert found["T1"]["obs_act/rgb/e"][0] == pytest.approx(0.5) and found["T2"]["obs_act/rgb/e"][0] == 0
    point, low, high = found["all tasks"]["obs_act/pointcloud/e"]
    assert point == pytest.approx(1.0) and low < 1.0 < high
    assert found["T1"]["obs_act/depth/e"] is None and "obs_act/none/e" not in found["T1"]


def test_a_perturbation_on_the_first_test_seeds_is_compared_with_the_nominal_outcome_on_those_seeds():
    """`perturbed_episodes`: the camera moved on the first 10 of 25 test seeds. The share kept compares those 10
    episodes with the same 10 unperturbed (5 of them succeed where 20 of 25 do), and the seed-by-seed agreement
    counts the nominal successes of those 10 alone."""
    nominal = "1" * 5 + "." * 5 + "1" * 15
    records = []
    for seed in range(3):
        r = record(f"p{seed}", "T", "pointcloud", 20, episodes=25, seed=seed)
        r["evaluations"]["none"]["per_seed"] = _per_seed(nominal, [9] * 25)
        moved = "1" * 5 + "." * 5  # the same five succeed
        r["evaluations"]["camera_yaw:10"] = {"successes": 5, "episodes": 10, "per_seed": _per_seed(moved, [9] * 10)}
        records.append(r)
    report = build_report(stored(*records))
    kept = report["checks"]["robustness"]["camera_yaw:10"]["T"]["obs_act/pointcloud/e"]
    assert kept[0] == pytest.approx(1.0)  # not (5/10) / (20/25) = 0.625
    agreement = report["checks"]["agreement"]["T | obs_act/pointcloud/e | camera_yaw:10"]
    assert (agreement["nominal_success"], agreement["episodes"], agreement["same_outcome"]) == (15, 30, 30)


def test_report_cli_with_published_table_only(tmp_path, capsys):
    table = tmp_path / "t.csv"
    table.write_text("task,A,B\nt1,0.5,0.7\nt2,0.3,0.1\n")
    assert (
        main(["report", "--table", str(table), "--out", str(tmp_path / "r"), "--json", str(tmp_path / "s.json")]) == 0
    )
    summary = json.loads((tmp_path / "s.json").read_text())["published"]
    assert summary == {
        "A": {"mean_sr": 0.4, "mean_rank": 1.5, "tasks": 2},
        "B": {"mean_sr": 0.4, "mean_rank": 1.5, "tasks": 2},
    }
    assert "Mean S.R." in capsys.readouterr().out
    table.write_text("task,A\nt1,x\n")
    assert main(["report", "--table", str(table)]) == 2
    assert "t.csv:2" in capsys.readouterr().err


def _per_seed(outcomes: str, lengths: list[int]) -> dict:
    return {"seeds": list(range(len(outcomes))), "success": outcomes, "length": lengths}


def test_blind_control_marks_and_per_seed_agreement(tmp_path):
    """▲ only where the interval clears the blind control's; agreement counted seed by seed against nominal."""
    n = 20

    def run(run_id, space, successes, camera=None):
        r = record(run_id, "T", space, successes, episodes=n)
        outcomes = "1" * successes + "." * (n - successes)
        r["evaluations"]["none"]["per_seed"] = _per_seed(outcomes, [5] * successes + [50] * (n - successes))
        if camera is not None:
            r["evaluations"]["camera_yaw:10"] = {
                "successes": camera[0].count("1"),
                "episodes": n,
                "per_seed": _per_seed(camera[0], camera[1]),
            }
        return r

    same = ("1" * 3 + "." * 17, [5] * 3 + [50] * 17)
    records = [
        run("b", "none", 3, camera=same),  # the blind control repeats every episode
        run("p", "pointcloud", 16, camera=("1" * 12 + "." * 8, [6] * 12 + [50] * 8)),
        run("r", "rgb", 6),  # overlaps the blind control
    ]
    report = build_report(stored(*records))
    blind = report["checks"]["beats_blind"]["T"]
    assert blind == {  # one training seed each: above blind is △, never ▲
        "obs_act/pointcloud/e": {"above": True, "mark": "△", "seeds": 1, "blind_seeds": 1},
        "obs_act/rgb/e": {"above": False, "mark": "", "seeds": 1, "blind_seeds": 1},
    }
    assert wilson_interval(16, n)[0] > wilson_interval(3, n)[1] and wilson_interval(6, n)[0] < wilson_interval(3, n)[1]
    md = write_report(report, tmp_path / "rep")["markdown"].read_text()
    assert "0.80 [0.58, 0.92] (16/20) △**" in md and ") ▲" not in md
    # one run against one run is no probability of improvement: said, not plotted
    assert report["checks"]["probability_of_improvement"] == {} and "probability_of_improvement.png" not in md
    assert "| obs_act/pointcloud/e | 1 | 0.80 | 0.80 | — (one seed each) |" in md
    assert "0.30 [0.15, 0.52] (6/20)</u>" in md
    agreement = report["checks"]["agreement"]
    assert agreement["T | obs_act/none/e | camera_yaw:10"] == {
        "success": 3,
        "nominal_success": 3,
        "same_outcome": 20,
        "identical": 20,
        "episodes": 20,
    }
    moved = agreement["T | obs_act/pointcloud/e | camera_yaw:10"]
    # 4 successes lost; the 12 kept took one step more, so only the 4 failures stayed identical
    assert (moved["same_outcome"], moved["identical"]) == (16, 4)
    assert (
        "| T | obs_act/pointcloud/e | camera_yaw:10 | 0.60 [0.39, 0.78] (12/20) | 0.80 (16/20) | 16/20 | 4/20 |" in md
    )


def test_a_lucky_seed_is_not_above_blind_and_a_consistent_method_is(tmp_path):
    """Three training seeds: blind 5/30 on each, rgb 30/30 then 3/30 twice (36/90 pooled, above blind's pooled
    Wilson interval), pointcloud 15/30 on each. Only pointcloud is ▲; the aggregates carry intervals."""
    outcomes = {"none": (5, 5, 5), "rgb": (30, 3, 3), "pointcloud": (15, 15, 15)}
    records = [
        record(f"{space}{seed}", "T", space, k, episodes=30, seed=seed)
        for space, ks in outcomes.items()
        for seed, k in enumerate(ks)
    ]
    assert wilson_interval(36, 90)[0] > wilson_interval(15, 90)[1]  # pooling episodes would call rgb better
    report = build_report(stored(*records))
    blind = report["checks"]["beats_blind"]["T"]
    assert blind["obs_act/rgb/e"] == {"above": False, "mark": "", "seeds": 3, "blind_seeds": 3}
    assert blind["obs_act/pointcloud/e"] == {"above": True, "mark": "▲", "seeds": 3, "blind_seeds": 3}
    aggregates = report["checks"]["aggregates"]
    point, low, high = aggregates["obs_act/pointcloud/e"]["iqm"]
    assert (point, low, high) == (pytest.approx(0.5), pytest.approx(0.5), pytest.approx(0.5))  # seeds agree
    point, low, high = aggregates["obs_act/rgb/e"]["iqm"]  # 3 runs: nothing to trim, the IQM is the mean
    assert point == pytest.approx(0.4) and low == pytest.approx(0.1) and high == pytest.approx(1.0)
    improvement = report["checks"]["probability_of_improvement"]
    # pointcloud beats every blind seed; rgb beats them on one seed of three
    assert improvement["obs_act/pointcloud/e > obs_act/none/e"] == [1.0, 1.0, 1.0]
    point, low, high = improvement["obs_act/rgb/e > obs_act/none/e"]
    assert point == pytest.approx(1 / 3) and low == 0.0 and high == 1.0
    assert report["warnings"] == []
    paths = write_report(report, tmp_path / "rep")
    md = paths["markdown"].read_text()
    assert "(45/90, 3 seeds) ▲" in md and "(36/90, 3 seeds)" in md and "(36/90, 3 seeds) ▲" not in md
    assert "| obs_act/rgb/e | 3 | 0.40 [0.10, 1.00] | 0.40 [0.10, 1.00] | 0.33 [0.00, 1.00] |" in md
    for name in ("aggregates.png", "probability_of_improvement.png"):
        assert (tmp_path / "rep" / name).read_bytes()[:4] == b"\x89PNG"
    reference = build_report(stored(*records), reference="obs_act/pointcloud/e")
    assert reference["checks"]["probability_of_improvement"]["obs_act/rgb/e > obs_act/pointcloud/e"][0] == (
        pytest.approx(1 / 3)
    )
    with pytest.raises(ReportError, match="--reference 'rgb' is not a column"):
        build_report(stored(*records), reference="rgb")


def test_controls_bracket_the_seeing_spaces_and_each_run_shows_its_outcomes_and_diagnostics(tmp_path):
    n = 20

    def run(run_id, space, outcomes, diagnostics=None):
        r = record(run_id, "T", space, outcomes.count("1"), episodes=n)
        r["evaluations"]["none"]["per_seed"] = _per_seed(outcomes, [9 if o == "1" else 50 for o in outcomes])
        if diagnostics:
            r["diagnostics"] = diagnostics
        return r

    records = [
        run("b", "none", "111" + "." * 17),
        run("o", "state", "1" * 18 + ".."),
        run(
            "p",
            "pointcloud",
            "1" * 13 + "." * 7,
            {
                "loss_curve": [[10, 0.5], [20, 0.25]],
                "open_loop_error": 0.125,
                "object_pixels": {"obj": 4.5},
                "object_token_share": 0.875,
            },
        ),
        run("r", "rgb", "..111" + "." * 15, {"loss_curve": [[20, 0.3]], "error": "ValueError: no frames"}),
    ]
    report = build_report(stored(*records))
    controls = report["checks"]["controls"]["T"]
    assert set(controls) == {"obs_act/pointcloud/e", "obs_act/rgb/e"}  # the controls are not bracketed
    assert controls["obs_act/pointcloud/e"]["gain_fraction"] == pytest.approx((13 - 3) / (18 - 3))
    assert controls["obs_act/rgb/e"]["gain_fraction"] == pytest.approx(0.0)
    assert (controls["obs_act/rgb/e"]["blind"], controls["obs_act/rgb/e"]["oracle"]) == (0.15, 0.9)
    md = write_report(report, tmp_path / "rep")["markdown"].read_text()
    assert "| T | obs_act/pointcloud/e | 0.15 | 0.65 | 0.90 | 0.67 |" in md
    assert "| T | obs_act/rgb/e | 0 | 0..19 | 00111000000000000000 |" in md  # per test seed, 1 = success
    assert "| T | obs_act/pointcloud/e | 0 | 0.250 (step 20) | 0.125 | obj 4.5 px | 0.88 |" in md
    assert "ValueError: no frames" in md  # a failed diagnostic is shown, not hidden
    assert (tmp_path / "rep" / "training_loss.png").stat().st_size > 1000
    # an oracle that does not beat blind leaves nothing to recover: no fraction
    flat = build_report(
        stored(
            run("b", "none", "1" * 10 + "." * 10),
            run("o", "state", "1" * 9 + "." * 11),
            run("p", "pointcloud", "1" * 12 + "." * 8),
        )
    )
    assert flat["checks"]["controls"]["T"]["obs_act/pointcloud/e"]["gain_fraction"] is None


def test_rlbench_rows_and_demonstration_counts_meet_the_papers_tables():
    from lerobot_obsbench.bench.report import resolve_table

    records = [
        record("a", "rlbench/open_drawer", "pointcloud", 3, episodes=25, demos=100),
        record("b", "rlbench/sweep_to_dustpan_of_size", "pointcloud", 5, episodes=25, demos=100),
        record("c", "rlbench/open_drawer", "pointcloud", 1, episodes=25, demos=10),
        record("d", "rlbench/sweep_to_dustpan_of_size", "pointcloud", 0, episodes=25, demos=10),
    ]
    report = build_report(stored(*records), read_published(resolve_table("table2_dp")), published_name="paper")
    # the paper's rows found from the task ids (Table 2 shortens some RLBench names)
    heading, (header, rows) = report["sections"][-1]
    assert heading == "Side by side on the shared rows (open drawer, sweep to)"
    cells = {name: {h: text for h, (text, _) in zip(header[1:], row, strict=True)} for name, row in rows}
    assert cells["open drawer"]["PCD-PointNet (paper)"].startswith("0.12")
    assert cells["sweep to"]["PCD-SpUNet (paper)"].startswith("0.08")
    assert cells["open drawer"]["obs_act/pointcloud/e"].startswith("0.12")  # 3/25 at 100 demonstrations
    report = build_report(stored(*records), read_published(resolve_table("table5_sample_efficiency")))
    heading, (header, rows) = report["sections"][-1]
    assert heading == "Side by side on the shared rows (10 demos, 100 demos)"
    cells = {name: {h: text for h, (text, _) in zip(header[1:], row, strict=True)} for name, row in rows}
    assert cells["10 demos"]["obs_act/pointcloud/e"].startswith("0.02")  # (1/25 + 0/25) / 2
    assert cells["100 demos"]["obs_act/pointcloud/e"].startswith("0.16")  # (3/25 + 5/25) / 2
    assert cells["100 demos"]["PointNet (published)"].startswith("0.32")


def test_every_record_written_twice_reports_exactly_what_once_does(tmp_path, capsys):
    """Two results files concatenated (or a copied line) used to turn one training seed into "2 seeds" and a △
    into a ▲: repeated run and evaluation ids are skipped, with one line saying how many."""
    records = stored(record("b", "T", "none", 3, episodes=30), record("p", "T", "pointcloud", 25, episodes=30))
    once, twice = tmp_path / "once.jsonl", tmp_path / "twice.jsonl"
    for line in records:
        append_result(once, line)
    twice.write_text(once.read_text() * 2)
    assert main(["report", str(once), "--out", str(tmp_path / "once")]) == 0
    capsys.readouterr()
    assert main(["report", str(twice), "--out", str(tmp_path / "twice")]) == 0
    assert f"{len(records)} repeated record(s) skipped" in capsys.readouterr().err
    assert (tmp_path / "twice" / "report.md").read_bytes() == (tmp_path / "once" / "report.md").read_bytes()
    assert "(25/30) △" in (tmp_path / "once" / "report.md").read_text()


def test_runs_differing_in_any_trained_field_are_separate_columns():
    """Every field of a grid run's config but the method, task, seed and demonstration count changes what is
    trained: two runs of one method and seed differing in any one of them are two columns, never one column of
    "2 seeds" (a budget or batch size edited and re-run into the same --out used to pool)."""
    from dataclasses import replace

    from lerobot_obsbench.bench.report import NOT_LABEL_FIELDS
    from lerobot_obsbench.bench.specs import RunSpec

    base = RunSpec("T", "rgb", "e", "obs_act", 0, 1e-3, 10, "cpu", 16, "steps", 100, 64, ("cam",), "pd_ee_delta_pose")
    changed = {
        "lr": 1e-4,
        "preset": "tiny",
        "batch_size": 8,
        "budget_unit": "frame_epochs",
        "budget": 200,
        "image_size": 128,
        "cameras": ("cam", "wrist"),
        "control_mode": "pd_joint_delta_pos",
        "policy_overrides": (("use_vae", False),),
        "language_goal": "clip",
    }
    assert set(changed) | set(NOT_LABEL_FIELDS) == set(base.config()) | {"language_goal"}  # every field perturbed
    for field, value in changed.items():
        other = replace(base, **{field: value})
        records = [
            {**record(run.run_id, "T", "rgb", 5), "config": run.config(), "method": run.method} for run in (base, other)
        ]
        cells = cells_by_task(records)["T"]
        assert len(cells) == 2 and all(cell.seeds == 1 for cell in cells.values()), field
        assert any(field in label for label in cells), (field, list(cells))


def test_aggregate_intervals_do_not_depend_on_the_global_numpy_state():
    """rliable draws its bootstrap from NumPy's global generator: the report's intervals are the same whatever
    ran before it, and the caller's random stream is left where it was."""
    import numpy as np

    from lerobot_obsbench.bench.aggregates import aggregate_estimates

    scores = {"a": np.array([[0.1, 0.5], [0.3, 0.7], [0.2, 0.9]])}
    np.random.seed(1)
    first = aggregate_estimates(scores)
    np.random.seed(2)
    expected_next = np.random.RandomState(2).random_sample()
    assert aggregate_estimates(scores) == first
    assert np.random.random_sample() == expected_next


def test_a_setting_that_differs_only_from_task_to_task_keeps_one_column():
    """The grid gives each task its own point-cloud crop box (policy_overrides.workspace): one method across
    tasks, not one column per task; the same field varied within a task still splits the method."""
    records = []
    for task, box in (("T1", [0, 1, 0, 1, 0, 1]), ("T2", [0, 2, 0, 2, 0, 2])):
        for seed in (0, 1):
            view = record(f"{task}-{seed}", task, "pointcloud", 5 + seed, seed=seed)
            view["config"]["policy_overrides"] = {"workspace": box}
            records.append(view)
    cells = cells_by_task(records)
    assert set(cells["T1"]) == set(cells["T2"]) == {"obs_act/pointcloud/e"}
    other = record("T1-wide", "T1", "pointcloud", 9, seed=0)
    other["config"]["policy_overrides"] = {"workspace": [0, 3, 0, 3, 0, 3]}
    split = cells_by_task([*records, other])
    assert [cell.seeds for cell in split["T1"].values()] == [2, 1] and len(split["T2"]) == 1


def test_a_report_of_one_grid_leaves_out_the_other_runs_of_its_folder(tmp_path, capsys):
    """`--grid`: a results file holding a grid's runs beside others (an older budget of the same method, another
    grid's pieces) reports the grid's runs only; a grid naming none of them is refused."""
    from lerobot_obsbench.bench.grid import load_grid

    grid = tmp_path / "g.yaml"
    grid.write_text("tasks: [PushCube-v1]\nobs_spaces: [rgb]\nsteps: 5\npreset: tiny\n")
    (run,) = load_grid(grid).expand()
    ours = record(run.run_id, "PushCube-v1", "rgb", 9)
    older = record("0123456789abcdef", "PushCube-v1", "rgb", 1)
    older["config"]["budget"] = 3  # the same method at another budget: another column without --grid
    results = tmp_path / "results.jsonl"
    results.write_text("".join(json.dumps(r) + "\n" for r in stored(ours, older)))
    assert main(["report", str(results), "--grid", str(grid), "--json", str(tmp_path / "s.json")]) == 0
    summary = json.loads((tmp_path / "s.json").read_text())
    assert list(summary["results"]) == ["obs_act/rgb/e"] and summary["results"]["obs_act/rgb/e"]["mean_sr"] == 0.9
    other = tmp_path / "other.yaml"
    other.write_text("tasks: [PickCube-v1]\nobs_spaces: [rgb]\nsteps: 5\npreset: tiny\n")
    assert main(["report", str(results), "--grid", str(other), "--out", str(tmp_path / "r2")]) == 2
    assert "the results hold none of the 1 runs grid" in capsys.readouterr().err
