# Every target installs what it needs first: the simulator's Vulkan driver (apt, scripts/setup_system.sh) and
# .venv with Python 3.12, lerobot 0.6.1, mani-skill 3.0.1 and this plugin. The interpreter is found by
# scripts/find_python.sh ($PYTHON, python3.12 on PATH, pyenv's 3.12, /usr/bin/python3.12); it fails with one line
# saying how to get one.
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install main lint test test-fast bench clean

$(STAMP): pyproject.toml scripts/setup_system.sh
	bash scripts/setup_system.sh
	@# a .venv left by an older set-up (Python 3.11, LeRobot 0.4.4) is replaced, not patched
	$(BIN)/python -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' 2>/dev/null || \
		{ rm -rf $(VENV) && PY=$$(bash scripts/find_python.sh) && $$PY -m venv $(VENV); }
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

# README main job: the `quick` benchmark grid (demos -> lerobot-train -> eval on held-out seeds -> report).
# Two units at a time, one thread each: a second unit doubles throughput, a second thread for one unit does far
# less (docs/performance.md).
# Resumable: rerunning after an interruption skips finished runs.
main: $(STAMP)
	$(BIN)/obsbench run quick --out outputs/bench/quick --workers 2
	$(BIN)/obsbench report outputs/bench/quick/results.jsonl --title "OBSBench quick: controls vs seeing spaces (CPU, not the paper's protocol)" \
		--json outputs/bench/quick/summary.json

# Code checks (configured in pyproject.toml): ruff lint + format, and the import-layer contracts.
CODE := lerobot_obsbench lerobot_policy_obsbench tests benchmarks scripts
lint: $(STAMP)
	$(BIN)/ruff check $(CODE)
	$(BIN)/ruff format --check $(CODE)
	$(BIN)/lint-imports --no-logo

# README test command: the code checks, then the whole suite, fast tests first, then the slow end-to-end ones, each
# in two processes with a test file each (its module fixtures stay in one process): the tests run one thread of
# Python apiece and the slow ones spend much of their time starting subprocesses and simulators, so two at a time
# finish sooner on 2 cores (times: docs/performance.md). A worker that crashes ends the run, naming its test:
# pytest-xdist 3.8 replaces a crashed worker under --dist loadfile and can then wait forever (its issue #1323).
test: lint
	$(BIN)/python -m pytest -m "not slow" -q -n 2 --dist loadfile --max-worker-restart 0
	$(BIN)/python -m pytest -m slow -q -n 2 --dist loadfile --max-worker-restart 0 --durations=10

test-fast: $(STAMP)
	$(BIN)/python -m pytest -m "not slow" -q -n 2 --dist loadfile --max-worker-restart 0

# Speed benchmarks (write JSON under benchmarks/results/).
bench: $(STAMP)
	$(BIN)/python -m benchmarks.bench_loading
	$(BIN)/python -m benchmarks.bench_depth_storage
	$(BIN)/python -m benchmarks.bench_preprocess
	$(BIN)/python -m benchmarks.bench_train_step
	$(BIN)/python -m benchmarks.bench_env
	$(BIN)/python -m benchmarks.bench_eval
	$(BIN)/python -m benchmarks.bench_demos
	$(BIN)/python -m benchmarks.bench_experts
	$(BIN)/python -m benchmarks.bench_step_variants
	$(BIN)/python -m benchmarks.bench_encoders
	$(BIN)/python -m benchmarks.bench_recording
	$(BIN)/python -m benchmarks.bench_latency

clean:
	rm -rf outputs .pytest_cache
