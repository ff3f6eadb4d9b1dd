#!/usr/bin/env bash
# Prints the path of a Python 3.12 interpreter that runs (LeRobot 0.6.1 is published for Python >= 3.12 only), or
# says where to get one and exits 1. A name on PATH is tested by running it: pyenv's `python3.12` shim is found by
# `command -v` yet exits 127 when pyenv's global version is another one.
set -uo pipefail

runs_312() {
    [ -n "$1" ] && "$1" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' >/dev/null 2>&1
}

candidates=("${PYTHON:-}" python3.12 python3)
if command -v pyenv >/dev/null 2>&1; then
    root=$(pyenv root)
    candidates+=($(ls -d "$root"/versions/3.12*/bin/python3.12 2>/dev/null | sort -V -r))
fi
candidates+=(/usr/bin/python3.12 /usr/local/bin/python3.12)
for candidate in "${candidates[@]}"; do
    if runs_312 "$candidate"; then
        command -v "$candidate"
        exit 0
    fi
done
echo "find_python: no working Python 3.12 found (tried \$PYTHON, python3.12, python3, pyenv's versions/3.12*," \
    "/usr/bin and /usr/local/bin). Install one (e.g. 'pyenv install 3.12' or Debian/Ubuntu's python3.12 and" \
    "python3.12-venv) or point PYTHON at it: make PYTHON=/path/to/python3.12 ..." >&2
exit 1
