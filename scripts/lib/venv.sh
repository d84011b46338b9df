# shellcheck shell=bash
# Sourced by scripts/mrswarm and scripts/test: the checkout's own virtual environment, ./.venv.
#
# mrswarm always installs into ./.venv of the checkout it runs from, never into the interpreter
# itself: two checkouts on one machine never run each other's code, and a dependency missing from
# pyproject.toml fails here as on a fresh machine. The venv is made from $PYTHON (default python3);
# Debian's and Ubuntu's python3 need python3-venv for it, installed with apt-get when missing.
#
#   mrswarm_venv EXTRAS   sets PY to ./.venv/bin/python, with the project installed editable with
#                         EXTRAS ("" or "test"); reinstalls only when pyproject.toml, the extras or
#                         the base interpreter changed since the last install.

_venv_say() { printf '==> %s\n' "$*" >&2; }
_venv_die() { printf '%s: %s\n' "$(basename "$0")" "$*" >&2; exit 2; }

mrswarm_venv() {
  local extras="$1" base
  base="$(command -v "${PYTHON:-python3}")" || _venv_die "no ${PYTHON:-python3} on PATH (apt-get install python3)"
  "$base" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
    || _venv_die "$base is $("$base" -V 2>&1); mrswarm needs Python >= 3.11"
  # an interpreter that is itself a venv's: make ours from the one it was made from
  base="$("$base" -c 'import os, sys; print(os.path.realpath(sys.executable) if sys.prefix == sys.base_prefix else os.path.join(sys.base_prefix, "bin", "python3"))')"

  if [ -x .venv/bin/python ] && [ "$(cat .venv/.mrswarm-base 2>/dev/null)" != "$base" ]; then
    _venv_say "./.venv was made from another interpreter; making it again from $base"
    rm -rf .venv
  fi
  if [ ! -x .venv/bin/python ]; then
    if ! "$base" -c 'import ensurepip, venv' >/dev/null 2>&1; then
      command -v apt-get >/dev/null 2>&1 || _venv_die "$base cannot make a virtualenv (no ensurepip) and there is no apt-get"
      local sudo=()
      if [ "$(id -u)" -ne 0 ]; then
        command -v sudo >/dev/null 2>&1 || _venv_die "python3-venv is missing: run 'apt-get install python3-venv' as root"
        sudo=(sudo)
      fi
      _venv_say "python3-venv (for ./.venv): apt-get install"
      DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get update -qq
      DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -qq python3-venv >/dev/null
    fi
    _venv_say "making ./.venv from $base ($("$base" -V 2>&1))"
    "$base" -m venv .venv
    echo "$base" > .venv/.mrswarm-base
  fi
  PY="$PWD/.venv/bin/python"

  # The stamp holds the inputs' hash and the extras installed with it: an install with the test
  # extra also serves scripts/mrswarm, one without it does not serve scripts/test.
  local want have stamp=".venv/.mrswarm-install"
  want="$( { echo "$base $PWD"; cat pyproject.toml; } | sha256sum | cut -d' ' -f1)"
  have="$(cat "$stamp" 2>/dev/null || true)"
  if [ "${have%% *}" != "$want" ] || { [ -n "$extras" ] && [ "${have#* }" != "$extras" ]; } \
     || ! "$PY" -c 'import mrswarm.cli' >/dev/null 2>&1; then
    local spec="."
    [ -n "$extras" ] && spec=".[$extras]"
    _venv_say "installing mrswarm into ./.venv (pip install -e '$spec'; a few minutes the first time)"
    "$PY" -m pip install --disable-pip-version-check -q -e "$spec"
    echo "$want $extras" > "$stamp"
  fi
}
