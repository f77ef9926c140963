#!/usr/bin/env bash
# The lower bounds in host/pyproject.toml are the versions tested: install exactly those (every
# runtime dependency at its ">=" version) into a separate venv and run the export and ingest tests
# that do not fly the simulator. Called by `make test` (target min-versions); about a minute once
# the venv exists (it is rebuilt when pyproject.toml changes).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
VENV=build/venv-min
STAMP="$VENV/.installed"
if [ ! -f "$STAMP" ] || [ host/pyproject.toml -nt "$STAMP" ]; then
  rm -rf "$VENV"
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/pip" install --quiet --upgrade pip
  # "name>=x.y" (or a pin "name==x.y") of [project].dependencies -> "name==x.y"
  # (written to a file first: a failure inside a process substitution would not stop the script)
  "$VENV/bin/python" - > "$VENV/pins.txt" <<'PY'
import re, tomllib
deps = tomllib.load(open("host/pyproject.toml", "rb"))["project"]["dependencies"]
for d in deps:
    m = re.fullmatch(r"\s*([A-Za-z0-9_.\-\[\]]+)\s*(?:>=|==)\s*([0-9][^,;\s]*)\s*", d)
    if not m:
        raise SystemExit(f"dependency without a plain lower bound: {d!r}")
    print(f"{m.group(1)}=={m.group(2)}")
PY
  mapfile -t PINS < "$VENV/pins.txt"
  echo "min-versions: ${PINS[*]}"
  "$VENV/bin/pip" install --quiet "${PINS[@]}"
  "$VENV/bin/pip" install --quiet --no-deps -e host
  "$VENV/bin/pip" install --quiet pytest pytest-timeout hypothesis "exiv2>=0.19.2"
  touch "$STAMP"
fi
"$VENV/bin/pip" check
"$VENV/bin/python" -m pytest -q --timeout 600 -p no:cacheprovider \
  tests/export/test_export_units.py tests/export/test_real_camera_jpegs.py tests/export/test_pose_tags_odm.py \
  tests/export/test_card_hygiene.py tests/ingest/test_foreign_and_damaged_logs.py tests/recording/test_recover.py
