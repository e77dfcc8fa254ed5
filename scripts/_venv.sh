# Shared by scripts/*: create or reuse .venv in the repo and install the project into it.
# Usage: [VENV_EXTRAS=test] source scripts/_venv.sh
# (extras come from VENV_EXTRAS, never from "$1": a sourced file sees its caller's arguments)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
EXTRAS="${VENV_EXTRAS:-}"
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
fi
STAMP="$VENV/.installed-$(cat "$ROOT/pyproject.toml" | python3 -c 'import hashlib,sys; print(hashlib.sha1(sys.stdin.buffer.read()).hexdigest()[:12])')${EXTRAS:+-$EXTRAS}"
if [ ! -f "$STAMP" ]; then
    echo "setting up $VENV (first run: installs the dependencies, about half a minute)..." >&2
    LOG="$VENV/install.log"
    PY="$VENV/bin/python"
    TARGET="$ROOT${EXTRAS:+[$EXTRAS]}"
    # uv (from the package index, into the venv) installs the same packages as pip in about half the time, their
    # bytecode compiled in parallel; where it cannot be had, pip does it.
    if ! { { "$PY" -m pip install "uv>=0.5" && "$PY" -m uv pip install --python "$PY" --compile-bytecode -e "$TARGET"; } \
           || { echo "uv failed; installing with pip" && "$PY" -m pip install --upgrade pip && "$PY" -m pip install -e "$TARGET"; }
         } >"$LOG" 2>&1; then
        tail -n 30 "$LOG" >&2
        echo "error: installing furuta-rt into $VENV failed; the full log is $LOG" >&2
        exit 1
    fi
    touch "$STAMP"
fi
export PATH="$VENV/bin:$PATH"
