#!/usr/bin/env bash
# Set up everything this project needs on a Debian machine, idempotently, then run a job.
#   ./setup.sh          set up only
#   ./setup.sh run      set up, then run the main job (the service on the simulated head)
#   ./setup.sh test     set up, then run the test suite (what CI runs)
# Extra arguments after run/test are passed on (to headctl / pytest).
set -euo pipefail
cd "$(dirname "$0")"
here=$(pwd)
venv="$here/.venv"
log() { printf '[setup] %s\n' "$*" >&2; }

# Debian packages: the Aravis 0.8 typelib and tools (GenICam cameras, and the fake GigE
# camera the tests use), and what building PyGObject < 3.51 needs.
debs=(gir1.2-aravis-0.8 aravis-tools libgirepository1.0-dev libcairo2-dev pkg-config gcc)
# The test job also drives the dashboard in a headless browser (tests/test_dashboard.py);
# the run job never pulls a browser.
if [ "${1:-}" = test ]; then debs+=(chromium chromium-driver); fi
python=${PYTHON:-python3}
if ! "$python" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
    debs+=(python3 python3-venv python3-dev); python=python3
fi
"$python" -c 'import ensurepip' 2>/dev/null || debs+=(python3-venv)
inc=$("$python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])' 2>/dev/null || true)
[ -f "$inc/Python.h" ] || debs+=(python3-dev)

missing=()
for p in "${debs[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    sudo=""; [ "$(id -u)" -eq 0 ] || sudo="sudo"
    log "installing Debian packages: ${missing[*]}"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# The virtual environment, reinstalled only when pyproject.toml changed.
if [ ! -x "$venv/bin/python" ]; then
    log "creating $venv"
    "$python" -m venv "$venv"
fi
stamp="$venv/.headctl-installed"
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    log "installing the package and its dependencies into $venv"
    "$venv/bin/python" -m pip install -q --upgrade pip >/dev/null
    # cyclonedds (the ROS 2 interface) has a wheel for x86_64 only: elsewhere docs/ros2.md builds it.
    extras="aravis,test"; [ "$(uname -m)" = x86_64 ] && extras="$extras,ros2"
    # foxglove-sdk (the live view in Foxglove) has wheels for these machines only.
    case "$(uname -m)" in x86_64|aarch64|armv7l) extras="$extras,foxglove" ;; esac
    "$venv/bin/python" -m pip install -q -e ".[$extras]"
    echo "$want" > "$stamp"
fi

job=${1:-}
[ $# -gt 0 ] && shift
case "$job" in
    "") log "ready: activate with  . .venv/bin/activate" ;;
    # The service: the daemon on the simulated head (configs/sim.yaml unless --config is given),
    # learning online until SIGTERM/Ctrl-C; `headctl status` in another shell shows its state.
    run) exec "$venv/bin/headctl" run "$@" ;;
    test)
        # The types first (strict on all three packages; pyproject.toml, [tool.mypy]), then
        # the suite. CI=true: no prompts, no colour; the suite itself never needs hardware.
        log "type check: mypy calib_free drivers headctl"
        "$venv/bin/python" -m mypy calib_free drivers headctl
        # On two workers unless HEADCTL_TEST_WORKERS says otherwise (0: in turn): they nearly
        # halve the time, which is mostly daemons started and waited on, not CPU.
        # --dist loadfile keeps a file's tests on one worker, in order, sharing its daemon.
        exec "$venv/bin/python" -m pytest -q -n "${HEADCTL_TEST_WORKERS:-2}" --dist loadfile "$@" ;;
    *) echo "usage: ./setup.sh [run|test] [args...]" >&2; exit 2 ;;
esac
