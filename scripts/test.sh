#!/usr/bin/env bash
# The whole test suite: bootstrap (idempotent), lint, then every package's
# test/ and the repo-level system tests. Exits non-zero on any failure.
#   scripts/test.sh                 # everything
#   scripts/test.sh -k belief       # extra arguments go to pytest
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO"

scripts/bootstrap.sh
# shellcheck disable=SC1091
set +u; source scripts/env.sh; set -u

echo "[test] ruff check"
ruff check .

echo "[test] pytest"
python -m pytest "$@"
