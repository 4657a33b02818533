#!/usr/bin/env bash
# install.sh: set up arbiterd, either as a developer checkout (dev/sim/test) or as a service.
#
#   ./install.sh dev                 developer venv (.venv) with the package editable + extras
#   ./install.sh sim [ARGS...]       dev, then run the daemon on the simulated robot
#   ./install.sh test [ARGS...]      dev, then run the whole test suite (pytest ARGS...)
#
# Every setting can come from the environment (ARBITERD_*) or a flag; see usage below and
# docs/deploy.md.
set -euo pipefail

SRCDIR="$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)"
PROG="install.sh"

PYTHON="${ARBITERD_PYTHON:-python3}"
DEV_VENV="${ARBITERD_DEV_VENV:-${SRCDIR}/.venv}"
DEV_EXTRAS="${ARBITERD_DEV_EXTRAS:-test,dev,bench}"
INTEROP_DIR="${SRCDIR}/tests/interop"
DRY_RUN="${ARBITERD_DRY_RUN:-0}"

######################################################################
# Messages and command runner
######################################################################

report_status() { printf '%s: %s\n' "${PROG}" "$*"; }
warn() { printf '%s: warning: %s\n' "${PROG}" "$*" >&2; }
die() { printf '%s: error: %s\n' "${PROG}" "$*" >&2; exit 1; }

# run CMD...: print and execute CMD, or only print it under --dry-run.
run() {
    if [[ "${DRY_RUN}" == 1 ]]; then
        printf '[dry-run] %s\n' "$*"
        return 0
    fi
    "$@"
}

is_root() { [[ "${EUID}" -eq 0 ]]; }

# as_root CMD...: run CMD as root, through sudo when we are not root.
as_root() {
    if is_root; then
        run "$@"
    elif command -v sudo >/dev/null 2>&1; then
        run sudo "$@"
    else
        die "'$*' needs root and sudo is not installed; run it as root"
    fi
}

sha256_of() { cat -- "$@" | sha256sum | cut -c1-64; }

######################################################################
# Developer set-up (dev / sim / test)
######################################################################

# The Debian packages the tests and the runtime need, each with the check that proves it present.
missing_dev_packages() {
    local missing=()
    "${PYTHON}" -c 'import ensurepip, venv' >/dev/null 2>&1 || missing+=(python3-venv)
    command -v node >/dev/null 2>&1 || missing+=(nodejs)
    command -v npm >/dev/null 2>&1 || missing+=(npm)
    [[ -x /usr/sbin/sshd ]] || command -v sshd >/dev/null 2>&1 || missing+=(openssh-server)
    command -v ssh >/dev/null 2>&1 && command -v ssh-keygen >/dev/null 2>&1 \
        || missing+=(openssh-client)
    command -v rsync >/dev/null 2>&1 || missing+=(rsync)
    command -v systemd-analyze >/dev/null 2>&1 || missing+=(systemd)
    (( ${#missing[@]} == 0 )) || printf '%s\n' "${missing[@]}"
}

# apt_install PKG...: install Debian packages non-interactively (as root or via sudo).
apt_install() {
    (( $# )) || return 0
    command -v apt-get >/dev/null 2>&1 \
        || die "missing system packages: $* (no apt-get here: install them with your package manager)"
    if ! is_root && ! command -v sudo >/dev/null 2>&1; then
        die "missing system packages: $*; run as root: apt-get install $*"
    fi
    report_status "installing system packages: $*"
    as_root env DEBIAN_FRONTEND=noninteractive apt-get update -q
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "$@"
}

check_python() {
    command -v "${PYTHON}" >/dev/null 2>&1 || die "${PYTHON} not found; install python3 (>= 3.11)"
    "${PYTHON}" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
        || die "$("${PYTHON}" -V 2>&1) is too old: arbiterd needs Python >= 3.11"
}

# Step 1: system packages the tests and the runtime need.
dev_step_system_packages() {
    local missing
    mapfile -t missing < <(missing_dev_packages)
    if (( ${#missing[@]} )); then
        apt_install "${missing[@]}"
    else
        report_status "system packages: all present"
    fi
}

# Step 2: the developer virtual environment with the package editable plus its extras.
dev_step_venv() {
    local stamp="${DEV_VENV}/.arbiterd-dev-stamp" want
    want="$(sha256_of "${SRCDIR}/pyproject.toml") ${DEV_EXTRAS} $("${PYTHON}" -V 2>&1)"
    if [[ -x "${DEV_VENV}/bin/python" && -f "${stamp}" && "$(cat "${stamp}")" == "${want}" ]]; then
        report_status "virtual environment ${DEV_VENV}: up to date"
        return 0
    fi
    if [[ ! -x "${DEV_VENV}/bin/python" ]]; then
        report_status "creating virtual environment ${DEV_VENV}"
        run "${PYTHON}" -m venv "${DEV_VENV}"
    fi
    report_status "installing arbiterd (editable) with extras [${DEV_EXTRAS}]"
    run "${DEV_VENV}/bin/python" -m pip install -q --disable-pip-version-check \
        -e "${SRCDIR}[${DEV_EXTRAS}]"
    [[ "${DRY_RUN}" == 1 ]] || printf '%s\n' "${want}" >"${stamp}"
}

# Step 3: the Node packages of the interop tests (roslib), when the tests pin them.
dev_step_node_packages() {
    local lock="${INTEROP_DIR}/package-lock.json" stamp="${INTEROP_DIR}/node_modules/.arbiterd-stamp"
    [[ -f "${lock}" ]] || { report_status "no ${lock#"${SRCDIR}"/}: skipping npm ci"; return 0; }
    if [[ -f "${stamp}" && "$(cat "${stamp}")" == "$(sha256_of "${lock}")" ]]; then
        report_status "node packages in tests/interop: up to date"
        return 0
    fi
    report_status "installing node packages in tests/interop (npm ci)"
    (cd "${INTEROP_DIR}" && run npm ci --no-audit --no-fund --loglevel=error)
    [[ "${DRY_RUN}" == 1 ]] || sha256_of "${lock}" >"${stamp}"
}

setup_dev() {
    check_python
    dev_step_system_packages
    dev_step_venv
    dev_step_node_packages
}

cmd_dev() {
    setup_dev
    report_status "ready: ${DEV_VENV}/bin/arbiterd run --sim  |  ./install.sh test"
}

cmd_sim() {
    setup_dev
    report_status "starting the daemon on the simulated robot (Ctrl-C stops it)"
    [[ "${DRY_RUN}" == 1 ]] && { run "${DEV_VENV}/bin/arbiterd" run --sim "$@"; return 0; }
    exec "${DEV_VENV}/bin/arbiterd" run --sim "$@"
}

cmd_test() {
    setup_dev
    report_status "running the test suite"
    cd "${SRCDIR}"
    [[ "${DRY_RUN}" == 1 ]] && { run "${DEV_VENV}/bin/python" -m pytest "$@"; return 0; }
    exec "${DEV_VENV}/bin/python" -m pytest "$@"
}

######################################################################
# Entry point
######################################################################

usage() {
    cat <<EOF
usage: ./install.sh COMMAND [OPTIONS]

Developer commands (run from a clone, as a normal user; apt packages go through sudo):
  dev                  set up .venv (package editable + test/dev/bench extras), npm ci for interop
  sim [ARGS...]        dev, then run 'arbiterd run --sim ARGS...' in the foreground
  test [ARGS...]       dev, then run 'python -m pytest ARGS...'

Options:
  --dry-run            print every action instead of doing it       (ARBITERD_DRY_RUN=1)
  -h, --help           this help

Environment: ARBITERD_PYTHON (python3), ARBITERD_DEV_VENV (.venv), ARBITERD_DEV_EXTRAS.
EOF
}

main() {
    local cmd="${1:-}"
    [[ -n "${cmd}" ]] || { usage >&2; exit 2; }
    shift
    case "${cmd}" in
        -h|--help|help) usage; return 0 ;;
    esac
    local rest=()
    if [[ "${cmd}" == dev ]]; then
        while (( $# )); do
            case "$1" in
                --dry-run) DRY_RUN=1 ;;
                -h|--help) usage; return 0 ;;
                *) die "unknown option for dev: $1 (see ./install.sh --help)" ;;
            esac
            shift
        done
    else
        rest=("$@")
    fi
    case "${cmd}" in
        dev) cmd_dev ;;
        sim) cmd_sim "${rest[@]}" ;;
        test) cmd_test "${rest[@]}" ;;
        *) printf '%s: error: unknown command %q\n' "${PROG}" "${cmd}" >&2; usage >&2; exit 2 ;;
    esac
}

main "$@"
