#!/usr/bin/env bash
# The whole test suite: bootstrap (idempotent), lint, then every package's
# test/ folder and the repo-level system tests, one pytest run per folder.
# Exits non-zero on any failure.
#   scripts/test.sh                 # everything
#   scripts/test.sh -k belief       # extra arguments go to every pytest run
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO"

scripts/bootstrap.sh
after_bootstrap=$SECONDS  # the suite's own time is counted from here
# shellcheck disable=SC1091
set +u; source scripts/env.sh; set -u

echo "[test] ruff check"
ruff check .

results="$REPO/build/test-results"
rm -rf "$results" && mkdir -p "$results"
status=0
for dir in tests abp_*/test; do
  [ -d "$dir" ] || continue
  name="${dir%%/*}"
  echo "[test] pytest $dir"
  python -m pytest "$dir" --durations=15 --junitxml="$results/$name.xml" "$@" || {
    rc=$?
    # 5 = no tests collected (e.g. filtered out by -k): not a failure of the suite.
    [ "$rc" = 5 ] || status=1
  }
done

python - "$results" "$((SECONDS - after_bootstrap))" <<'PY'
import pathlib, sys
import xml.etree.ElementTree as ET
results = pathlib.Path(sys.argv[1])
totals = dict(tests=0, failures=0, errors=0, skipped=0)
durations = []  # (seconds, test id): every test's setup + call + teardown, from junit
for path in sorted(results.glob("*.xml")):
    for suite in ET.parse(path).getroot().iter("testsuite"):
        for key in totals:
            totals[key] += int(suite.get(key, 0))
        for case in suite.iter("testcase"):
            durations.append((float(case.get("time", 0)),
                              f"{case.get('classname')}::{case.get('name')}"))
durations.sort(reverse=True)
lines = [f"{t:8.2f}  {name}" for t, name in durations]
(results / "durations.txt").write_text(
    f"# per-test durations (s), slowest first; {sum(t for t, _ in durations):.0f} s in tests,"
    f" {sys.argv[2]} s for lint and tests after the bootstrap\n" + "\n".join(lines) + "\n")
print(f"[test] {sys.argv[2]} s after the bootstrap, {sum(t for t, _ in durations):.0f} s in tests;"
      f" every test's duration: {results / 'durations.txt'}; the slowest:")
print("\n".join(lines[:10]))
failed = totals["failures"] + totals["errors"]
passed = totals["tests"] - failed - totals["skipped"]
print(f"[test] all folders: {passed} passed, {failed} failed, {totals['skipped']} skipped")
print(f"{passed} passed, {failed} failed")
PY
exit "$status"
