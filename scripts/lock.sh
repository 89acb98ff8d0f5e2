#!/usr/bin/env bash
# Rebuild requirements.lock: resolve requirements.txt in a throw-away venv and freeze it.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
python3 -m venv "$tmp/venv"
"$tmp/venv/bin/pip" install -q --upgrade pip
"$tmp/venv/bin/pip" install -q -r "$ROOT/requirements.txt"
"$tmp/venv/bin/python" "$ROOT/scripts/freeze.py" > "$ROOT/requirements.lock"
echo "requirements.lock: $(wc -l < "$ROOT/requirements.lock") packages"
