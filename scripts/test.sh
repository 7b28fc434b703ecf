#!/usr/bin/env bash
# The tests: the Rust workspace's, then the Python package's against a build of it in
# target/python-venv (made on first use; PYTHON picks the interpreter, default python3).
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== cargo test"
cargo test --release --workspace

echo "== python tests"
venv="$PWD/target/python-venv"
if [ ! -x "$venv/bin/python" ]; then
    "${PYTHON:-python3}" -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet -r crates/pfslam-py/requirements-test.txt
# The release profile and target/ of the workspace: the library built above is reused.
(cd crates/pfslam-py && VIRTUAL_ENV="$venv" "$venv/bin/maturin" develop --release --quiet)
"$venv/bin/python" -m pytest crates/pfslam-py/tests
