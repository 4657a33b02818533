#!/usr/bin/env bash
# deploy-pi.sh: ship this checkout to a robot over ssh as a new release, switch to it, and roll
# back automatically when the new release does not answer /api/health.
#
#   ./deploy-pi.sh [user@]host [--port N] [--identity FILE] [--keep N] [--hardware|--sim]
#   ./deploy-pi.sh [user@]host --rollback
#
# The robot needs ssh, python3 (Raspberry Pi OS Bookworm has both), passwordless sudo for a
# non-root user (the Pi OS default), and preferably rsync. docs/deploy.md has the details.
set -euo pipefail

SRCDIR="$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)"
PROG="deploy-pi.sh"
PREFIX=/opt/arbiterd

TARGET=""
PORT="${ARBITERD_SSH_PORT:-22}"
IDENTITY="${ARBITERD_SSH_IDENTITY:-}"
SSH_OPTS="${ARBITERD_SSH_OPTS:-}"              # extra ssh options, e.g. "-o ProxyJump=gw"
KEEP="${ARBITERD_KEEP_RELEASES:-5}"
HEALTH_TIMEOUT="${ARBITERD_HEALTH_TIMEOUT:-60}"
REMOTE_ROOT="${ARBITERD_REMOTE_ROOT:-}"        # a staging root on the robot (tests)
PYTHON="${ARBITERD_PYTHON:-}"
WHEEL="" WHEELHOUSE="" ROLLBACK=0
INSTALL_FLAGS=()
EXIT_UNHEALTHY=3                               # install.sh: active but failed its health check

report_status() { printf '%s: %s\n' "${PROG}" "$*"; }
die() { printf '%s: error: %s\n' "${PROG}" "$*" >&2; exit 1; }
usage_error() { printf '%s: error: %s (see ./deploy-pi.sh --help)\n' "${PROG}" "$*" >&2; exit 2; }

usage() {
    cat <<EOF
usage: ./deploy-pi.sh [user@]host [OPTIONS]

Builds a wheel of this checkout, copies it with the installer into a new release directory
${PREFIX}/releases/<version>-<time> on the robot, installs it (install.sh systemd), switches
${PREFIX}/current to it, restarts arbiterd and waits for /api/health. If the new release is
not healthy it switches back to the previous release, restarts that, and exits 1.

Options:
  --port N             ssh port (default 22)                    ARBITERD_SSH_PORT
  --identity FILE      ssh private key                           ARBITERD_SSH_IDENTITY
  --rollback           switch back to the previous release now, and restart it
  --keep N             releases kept on the robot (default ${KEEP})  ARBITERD_KEEP_RELEASES
  --health-timeout S   seconds to wait for /api/health (default ${HEALTH_TIMEOUT})
  --hardware | --sim   run the real robot / the simulated one (default: keep the robot's choice)
  --driver NAME        [driver] type written into a first-time config
  --wheel FILE         deploy this wheel instead of building one
  --wheelhouse DIR     ship the wheels in DIR too and install offline from them (they must
                       cover every dependency for the robot's Python and CPU)
  --remote-root DIR    install into a staging root DIR on the robot (for tests)
  -h, --help           this help

Environment: ARBITERD_SSH_OPTS (extra ssh options), ARBITERD_PYTHON (python that builds the
wheel; default .venv/bin/python, else python3).
EOF
}

need_value() { (( $1 > 1 )) || usage_error "$2 needs a value"; }

parse_args() {
    while (( $# )); do
        case "$1" in
            --port) need_value $# "$1"; PORT="$2"; shift ;;
            --identity|-i) need_value $# "$1"; IDENTITY="$2"; shift ;;
            --rollback) ROLLBACK=1 ;;
            --keep) need_value $# "$1"; KEEP="$2"; shift ;;
            --health-timeout) need_value $# "$1"; HEALTH_TIMEOUT="$2"; shift ;;
            --hardware|--sim) INSTALL_FLAGS+=("$1") ;;
            --driver) need_value $# "$1"; INSTALL_FLAGS+=(--driver "$2"); shift ;;
            --wheel) need_value $# "$1"; WHEEL="$2"; shift ;;
            --wheelhouse) need_value $# "$1"; WHEELHOUSE="$2"; shift ;;
            --remote-root) need_value $# "$1"; REMOTE_ROOT="$2"; shift ;;
            -h|--help) usage; exit 0 ;;
            -*) usage_error "unknown option: $1" ;;
            *) [[ -z "${TARGET}" ]] || usage_error "one host only (got ${TARGET} and $1)"
               TARGET="$1" ;;
        esac
        shift
    done
    [[ -n "${TARGET}" ]] || usage_error "which robot? give [user@]host"
    [[ "${PORT}" =~ ^[0-9]+$ ]] || usage_error "--port ${PORT}: not a port number"
    if ! [[ "${KEEP}" =~ ^[0-9]+$ ]] || (( KEEP < 2 )); then usage_error "--keep ${KEEP}: need >= 2"; fi
    [[ -z "${IDENTITY}" || -r "${IDENTITY}" ]] || usage_error "--identity ${IDENTITY}: unreadable"
    [[ -z "${WHEEL}" || -f "${WHEEL}" ]] || usage_error "--wheel ${WHEEL}: no such file"
    [[ -z "${WHEELHOUSE}" || -d "${WHEELHOUSE}" ]] \
        || usage_error "--wheelhouse ${WHEELHOUSE}: no such directory"
    return 0
}

######################################################################
# ssh plumbing
######################################################################

SSH=()
SUDO=""

setup_ssh() {
    SSH=(ssh -p "${PORT}" -o BatchMode=yes -o ConnectTimeout=15)
    [[ -z "${IDENTITY}" ]] || SSH+=(-i "${IDENTITY}" -o IdentitiesOnly=yes)
    # shellcheck disable=SC2206  # ARBITERD_SSH_OPTS is a list of words on purpose
    SSH+=(${SSH_OPTS})
}

# remote WORD...: run one command on the robot; each word is quoted for the remote shell.
remote() {
    local words
    printf -v words '%q ' "$@"
    "${SSH[@]}" "${TARGET}" "${words}"
}

# remote_sh SCRIPT: run a shell snippet on the robot as written (no quoting).
remote_sh() { "${SSH[@]}" "${TARGET}" "$1"; }

rpath() { printf '%s%s' "${REMOTE_ROOT}" "$1"; }   # a robot path, inside the staging root

# Step 1: reach the robot, and decide whether it needs sudo.
step_check_robot() {
    local info uid
    info="$(remote_sh 'id -u; command -v rsync || echo none; command -v python3 || echo none')" \
        || die "cannot run commands on ${TARGET} over ssh (port ${PORT}); check the host, the key and that sshd runs"
    uid="$(sed -n 1p <<<"${info}")"
    [[ "$(sed -n 3p <<<"${info}")" != none ]] || die "${TARGET} has no python3"
    HAVE_RSYNC=1
    [[ "$(sed -n 2p <<<"${info}")" != none ]] || HAVE_RSYNC=0
    if [[ "${uid}" != 0 && -z "${REMOTE_ROOT}" ]]; then
        SUDO="sudo -n"
        remote sudo -n true 2>/dev/null \
            || die "${TARGET}: the ssh user needs passwordless sudo (Raspberry Pi OS's default user has it)"
    fi
    report_status "robot ${TARGET} reachable (uid ${uid}${SUDO:+, using sudo})"
}

# Step 2: the wheel of this checkout.
step_build_wheel() {
    if [[ -n "${WHEEL}" ]]; then
        WHEEL="$(realpath -- "${WHEEL}")"
        return 0
    fi
    local python="${PYTHON}"
    if [[ -z "${python}" ]]; then
        python=python3
        [[ -x "${SRCDIR}/.venv/bin/python" ]] && python="${SRCDIR}/.venv/bin/python"
    fi
    report_status "building the wheel with ${python}"
    "${python}" -m pip wheel --no-deps --disable-pip-version-check -q -w "${WORKDIR}/dist" \
        "${SRCDIR}" >"${WORKDIR}/build.log" 2>&1 \
        || { cat "${WORKDIR}/build.log" >&2; die "building the wheel failed"; }
    WHEEL="$(ls "${WORKDIR}"/dist/arbiterd-*.whl)"
}

# Step 3: what goes into the release directory: the wheel, the installer, the units.
step_stage() {
    local stage="${WORKDIR}/stage" version
    mkdir -p "${stage}/systemd"
    cp "${WHEEL}" "${stage}/"
    cp "${SRCDIR}/install.sh" "${stage}/"
    cp "${SRCDIR}"/systemd/* "${stage}/systemd/"
    if [[ -n "${WHEELHOUSE}" ]]; then
        mkdir -p "${stage}/wheels"
        cp "${WHEELHOUSE}"/*.whl "${stage}/wheels/"
    fi
    version="$(basename "${WHEEL}" | cut -d- -f2)"
    RELEASE="${version}-$(date -u +%Y%m%dT%H%M%SZ)-$(od -An -N3 -tx1 /dev/urandom | tr -d ' \n')"
    RELDIR="$(rpath "${PREFIX}/releases/${RELEASE}")"
}

# Step 4: copy it into the new release directory on the robot.
step_upload() {
    report_status "copying release ${RELEASE} to ${TARGET}:${RELDIR}"
    remote_sh "${SUDO} mkdir -p $(printf '%q' "${RELDIR}")"
    if (( HAVE_RSYNC )) && command -v rsync >/dev/null 2>&1; then
        local rsh
        printf -v rsh '%q ' "${SSH[@]}"
        rsync -a --delete -e "${rsh}" ${SUDO:+--rsync-path="${SUDO} rsync"} \
            "${WORKDIR}/stage/" "${TARGET}:${RELDIR}/"
    else
        tar -C "${WORKDIR}/stage" -cf - . \
            | remote_sh "${SUDO} tar -C $(printf '%q' "${RELDIR}") -xf -"
    fi
}

installer() {
    local args=("$1/install.sh" "${@:2}" --health-timeout "${HEALTH_TIMEOUT}")
    [[ -z "${REMOTE_ROOT}" ]] || args+=(--root "${REMOTE_ROOT}")
    # shellcheck disable=SC2086  # SUDO is empty or "sudo -n"
    remote ${SUDO} "${args[@]}"
}

current_release() {
    remote readlink "$(rpath "${PREFIX}/current")" 2>/dev/null | sed 's|^releases/||' || true
}

# Step 5: install and activate it; on a failed health check (or any failure after the switch)
# go back to the release that ran before.
step_install() {
    local before rc=0 now
    before="$(current_release)"
    report_status "installing ${RELEASE} (running before: ${before:-none})"
    installer "${RELDIR}" systemd --wheel "${RELDIR}/$(basename "${WHEEL}")" \
        --release "${RELEASE}" --keep "${KEEP}" "${INSTALL_FLAGS[@]}" || rc=$?
    if (( rc == 0 )); then
        report_status "deployed ${RELEASE}: healthy"
        return 0
    fi
    now="$(current_release)"
    if [[ "${now}" != "${RELEASE}" ]]; then
        die "installing ${RELEASE} failed (exit ${rc}) before it was activated; ${before:-nothing} still runs"
    fi
    if [[ "${rc}" == "${EXIT_UNHEALTHY}" ]]; then
        report_status "FAILED: ${RELEASE} did not become healthy within ${HEALTH_TIMEOUT}s"
    else
        report_status "FAILED: installing ${RELEASE} failed (exit ${rc}) after the switch"
    fi
    [[ -n "${before}" ]] || die "no previous release to roll back to; the robot runs the failed ${RELEASE}"
    report_status "rolling back to ${before}"
    installer "$(rpath "${PREFIX}/releases/${before}")" rollback \
        || die "ROLLBACK FAILED: ${before} is not healthy either; log in and check ./install.sh status"
    die "deploy of ${RELEASE} failed its health check; rolled back to ${before}, which is healthy"
}

cmd_rollback() {
    local current
    current="$(current_release)"
    [[ -n "${current}" ]] || die "${TARGET} has no arbiterd release installed"
    installer "$(rpath "${PREFIX}/releases/${current}")" rollback \
        || die "rollback on ${TARGET} failed"
    report_status "rolled back from ${current} to $(current_release)"
}

main() {
    parse_args "$@"
    WORKDIR="$(mktemp -d)"
    trap 'rm -rf -- "${WORKDIR}"' EXIT
    setup_ssh
    step_check_robot
    if (( ROLLBACK )); then
        cmd_rollback
        return 0
    fi
    step_build_wheel
    step_stage
    step_upload
    step_install
}

main "$@"
