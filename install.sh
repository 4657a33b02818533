#!/usr/bin/env bash
# install.sh: set up arbiterd, either as a developer checkout (dev/sim/test) or as a service.
#
#   ./install.sh dev                 developer venv (.venv) with the package editable + extras
#   ./install.sh sim [ARGS...]       dev, then run the daemon on the simulated robot
#   ./install.sh test [ARGS...]      dev, then the gates (ruff, mypy), then the test suite (pytest ARGS...)
#   sudo ./install.sh systemd [--hardware] [--driver NAME]   the supervised service on a Pi
#
# Every setting can come from the environment (ARBITERD_*) or a flag; see usage below and
# docs/deploy.md.
set -euo pipefail

SRCDIR="$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)"
PROG="install.sh"

PYTHON="${ARBITERD_PYTHON:-python3}"
DEV_VENV="${ARBITERD_DEV_VENV:-${SRCDIR}/.venv}"
DEV_EXTRAS="${ARBITERD_DEV_EXTRAS:-test,dev,bench,ros2,ros2-test,fleet,camera}"
# ROS 2 Kilted's rclpy for the ROS 2 face's tests: it installs `rclpy` as Jazzy's does, so it
# lives in a venv of its own (tests/ros2_netns/kilted-requirements.txt; x86_64 Linux only)
KILTED_VENV="${ARBITERD_KILTED_VENV:-${SRCDIR}/.venv-kilted}"
KILTED_REQUIREMENTS=tests/ros2_netns/kilted-requirements.txt
NODE_TEST_DIRS=(tests/interop tests/console)   # npm ci in each (lock files committed)
WITH_BROWSER=0   # test mode: Debian's chromium for the web console's browser tests
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
        printf '[dry-run]'
        printf ' %q' "$@"
        printf '\n'
        return 0
    fi
    "$@"
}

is_root() { [[ "${EUID}" -eq 0 ]]; }

# as_root CMD...: run CMD as root, through sudo when we are not root.
as_root() {
    if is_root || [[ "${DRY_RUN}" == 1 ]]; then
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

# The Debian packages running the daemon needs (./install.sh sim), with the check that proves
# each present.
missing_run_packages() {
    "${PYTHON}" -c 'import ensurepip, venv' >/dev/null 2>&1 || echo python3-venv
    return 0
}

# The Debian packages the tests add (./install.sh dev and test), each with its check.
# python_headers_present: Python.h of the Python the venv is made from (a C extension's build
# needs it; Debian ships it in python3-dev, not in python3).
python_headers_present() {
    local include
    include="$("${PYTHON}" -c 'import sysconfig; print(sysconfig.get_path("include"))' 2>/dev/null)"
    [[ -n "${include}" && -e "${include}/Python.h" ]]
}

missing_test_packages() {
    local missing=()
    command -v node >/dev/null 2>&1 || missing+=(nodejs)
    command -v npm >/dev/null 2>&1 || missing+=(npm)
    [[ -x /usr/sbin/sshd ]] || command -v sshd >/dev/null 2>&1 || missing+=(openssh-server)
    command -v ssh >/dev/null 2>&1 && command -v ssh-keygen >/dev/null 2>&1 \
        || missing+=(openssh-client)
    command -v rsync >/dev/null 2>&1 || missing+=(rsync)
    command -v systemd-analyze >/dev/null 2>&1 || missing+=(systemd)
    # the ros2 extra's cyclonedds binding is built against Debian's Cyclone DDS (docs/ros2.md):
    # with a C compiler and the Python headers, which a minimal Debian (the Pi's OS) lacks
    [[ -e /usr/include/dds/dds.h ]] || missing+=(cyclonedds-dev)
    if ! dev_venv_current "${DEV_EXTRAS}"; then  # the venv gets (re)built: the binding compiles
        command -v "${ARBITERD_CC:-gcc}" >/dev/null 2>&1 || missing+=(gcc)
        python_headers_present || missing+=(python3-dev)
    fi
    if [[ "${WITH_BROWSER}" == 1 ]]; then
        [[ -x "${ARBITERD_CHROMIUM:-/usr/bin/chromium}" ]] || missing+=(chromium)
    fi
    (( ${#missing[@]} == 0 )) || printf '%s\n' "${missing[@]}"
}

# apt_install PKG...: install Debian packages non-interactively (as root or via sudo).
apt_install() {
    (( $# )) || return 0
    command -v apt-get >/dev/null 2>&1 \
        || die "missing system packages: $* (no apt-get here: install them with your package manager)"
    if ! is_root && [[ "${DRY_RUN}" != 1 ]] && ! command -v sudo >/dev/null 2>&1; then
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

# venv_bootstrap PYTHON [PIP ARGS...]: bring pip, setuptools and wheel up to date in a new venv.
# Debian 12's venvs (Raspberry Pi OS too) start with pip 23.0.1 and no `wheel`, which cannot
# build the wheels of sdist-only dependencies (sdnotify: "invalid command 'bdist_wheel'").
venv_bootstrap() {
    local python="$1"
    shift
    report_status "updating pip, setuptools and wheel in $(dirname "$(dirname "${python}")")"
    run "${python}" -m pip install -q --disable-pip-version-check --upgrade "$@" \
        pip setuptools wheel && return 0
    [[ " $* " == *" --no-index "* ]] \
        || die "could not update pip in $(dirname "$(dirname "${python}")"); is the package index reachable?"
    warn "the offline wheelhouse has no pip/setuptools/wheel: keeping the venv's own pip, which installs wheels but may not build sdists"
}

# Step 1: system packages: what running needs (sim), plus what the tests need (dev, test).
dev_step_system_packages() {
    local purpose="$1" missing
    mapfile -t missing < <(missing_run_packages
                           [[ "${purpose}" == run ]] || missing_test_packages)
    if (( ${#missing[@]} )); then
        apt_install "${missing[@]}"
    else
        report_status "system packages: all present"
    fi
}

# Step 2: the developer virtual environment with the package editable plus EXTRAS. The stamp
# holds the pyproject hash, the Python version and the extras installed; a venv with more
# extras than asked for is up to date.
# dev_venv_current EXTRAS: the developer venv exists, was made from this pyproject.toml and
# this Python, and holds EXTRAS (its stamp says so).
dev_venv_current() {
    local stamp="${DEV_VENV}/.arbiterd-dev-stamp" want
    [[ -x "${DEV_VENV}/bin/python" && -f "${stamp}" ]] || return 1
    want="$(sha256_of "${SRCDIR}/pyproject.toml") $("${PYTHON}" -V 2>&1)"
    [[ "$(sed -n 1p "${stamp}")" == "${want}" ]] && venv_has_extras "$(sed -n 2p "${stamp}")" "$1"
}

dev_step_venv() {
    local extras="$1" stamp="${DEV_VENV}/.arbiterd-dev-stamp" want
    want="$(sha256_of "${SRCDIR}/pyproject.toml") $("${PYTHON}" -V 2>&1)"
    if dev_venv_current "${extras}"; then
        report_status "virtual environment ${DEV_VENV}: up to date"
        return 0
    fi
    if [[ ! -x "${DEV_VENV}/bin/python" ]]; then
        report_status "creating virtual environment ${DEV_VENV}"
        run "${PYTHON}" -m venv "${DEV_VENV}"
    fi
    venv_bootstrap "${DEV_VENV}/bin/python"
    report_status "installing arbiterd (editable)${extras:+ with extras [${extras}]}"
    run env CYCLONEDDS_HOME="$(cyclonedds_home "${DEV_VENV}")" \
        "${DEV_VENV}/bin/python" -m pip install -q --disable-pip-version-check \
        -e "${SRCDIR}${extras:+[${extras}]}"
    [[ "${DRY_RUN}" == 1 ]] || printf '%s\n%s\n' "${want}" "${extras}" >"${stamp}"
}

# cyclonedds_home VENV: a folder the cyclonedds binding's build finds Debian's Cyclone DDS in
# (it wants include/, bin/ and lib/libddsc.so under one folder; Debian splits them by
# multiarch), made inside VENV; prints its path.
cyclonedds_home() {
    local home="$1/cyclonedds-home" lib
    for lib in /usr/lib/*/libddsc.so; do
        [[ "${DRY_RUN}" != 1 && -e "${lib}" ]] || continue
        mkdir -p "${home}"
        ln -sfn /usr/include "${home}/include"
        ln -sfn /usr/bin "${home}/bin"
        ln -sfn "$(dirname "${lib}")" "${home}/lib"
        break
    done
    printf '%s\n' "${home}"
}

# venv_has_extras HAVE WANT: every comma-separated extra of WANT is in HAVE.
venv_has_extras() {
    local extra
    for extra in ${2//,/ }; do
        [[ ",$1," == *",${extra},"* ]] || return 1
    done
    return 0
}

# Step 2b: with the ros2-test extra, the venv with ROS 2 Kilted's rclpy (tests only; PyPI's
# wheels are x86_64 Linux only, elsewhere the Kilted checks skip). Stamped with the
# requirements file's hash.
dev_step_kilted_venv() {
    local reqs="${SRCDIR}/${KILTED_REQUIREMENTS}" stamp="${KILTED_VENV}/.arbiterd-stamp" want
    [[ ",$1," == *",ros2-test,"* ]] || return 0
    [[ "$(uname -s)-$(uname -m)" == Linux-x86_64 && -f "${reqs}" ]] || return 0
    want="$(sha256_of "${reqs}") $("${PYTHON}" -V 2>&1)"
    if [[ -x "${KILTED_VENV}/bin/python" && -f "${stamp}" && "$(cat "${stamp}")" == "${want}" ]]; then
        report_status "ROS 2 Kilted venv ${KILTED_VENV}: up to date"
        return 0
    fi
    report_status "creating the ROS 2 Kilted venv ${KILTED_VENV} (${KILTED_REQUIREMENTS})"
    [[ -x "${KILTED_VENV}/bin/python" ]] || run "${PYTHON}" -m venv "${KILTED_VENV}"
    run "${KILTED_VENV}/bin/python" -m pip install -q --disable-pip-version-check -r "${reqs}"
    [[ "${DRY_RUN}" == 1 ]] || printf '%s\n' "${want}" >"${stamp}"
}

# Step 3: the Node packages of the tests that run real JavaScript clients (roslib, the
# console's browser driver), from their committed lock files.
dev_step_node_packages() {
    local rel dir lock stamp
    for rel in "${NODE_TEST_DIRS[@]}"; do
        dir="${SRCDIR}/${rel}" lock="${SRCDIR}/${rel}/package-lock.json"
        stamp="${dir}/node_modules/.arbiterd-stamp"
        [[ -f "${lock}" ]] || { report_status "no ${rel}/package-lock.json: skipping npm ci"; continue; }
        if [[ -f "${stamp}" && "$(cat "${stamp}")" == "$(sha256_of "${lock}")" ]]; then
            report_status "node packages in ${rel}: up to date"
            continue
        fi
        report_status "installing node packages in ${rel} (npm ci)"
        (cd "${dir}" && run npm ci --no-audit --no-fund --loglevel=error)
        [[ "${DRY_RUN}" == 1 ]] || sha256_of "${lock}" >"${stamp}"
    done
}

# The clone's packages compiled to bytecode, as pip leaves an installed package: without it
# every start compiles them again wherever Python may not write its cache (a read-only clone,
# PYTHONDONTWRITEBYTECODE), ~0.6 s of the daemon's start on a 2-core box (docs/benchmarks.md).
dev_step_bytecode() {
    local dirs
    read -r -a dirs <<<"$(source_packages)"
    report_status "compiling the sources to bytecode (${dirs[*]})"
    (cd "${SRCDIR}" && run "${DEV_VENV}/bin/python" -m compileall -q "${dirs[@]}") \
        || warn "could not compile the sources to bytecode: the daemon starts, but more slowly"
}

# setup_dev run|test: the clone set up for running the daemon, or for developing and testing.
setup_dev() {
    check_python
    dev_step_system_packages "$1"
    if [[ "$1" == run ]]; then
        dev_step_venv ""
    else
        dev_step_venv "${DEV_EXTRAS}"
        dev_step_kilted_venv "${DEV_EXTRAS}"
        dev_step_node_packages
    fi
    dev_step_bytecode
}

cmd_dev() {
    setup_dev test
    report_status "ready: ${DEV_VENV}/bin/arbiterd run --sim, then open http://localhost:8085/  |  ./install.sh test"
}

# http_port_of ARGS...: the --http-port that `arbiterd run` is given, else 8085.
http_port_of() {
    local port=8085
    while (( $# )); do
        case "$1" in
            --http-port) port="${2:-${port}}"; shift ;;
            --http-port=*) port="${1#--http-port=}" ;;
        esac
        shift
    done
    printf '%s\n' "${port}"
}

cmd_sim() {
    setup_dev run
    warn_if_service_runs
    report_status "starting the daemon on the simulated robot: open http://localhost:$(http_port_of "$@")/ (Ctrl-C stops it)"
    [[ "${DRY_RUN}" == 1 ]] && { run "${DEV_VENV}/bin/arbiterd" run --sim "$@"; return 0; }
    exec "${DEV_VENV}/bin/arbiterd" run --sim "$@"
}

# On a robot with the service installed and running, its ports are taken.
warn_if_service_runs() {
    command -v systemctl >/dev/null 2>&1 || return 0
    systemctl is-active --quiet arbiterd.service 2>/dev/null || return 0
    warn "the arbiterd service runs on this machine and holds its HTTP and rosbridge ports; stop it first (sudo systemctl stop robot.target) or give this one other ports: ./install.sh sim --http-port PORT --ws-port PORT"
}

# run_gate NAME CMD...: a check that must pass before the tests run; stops at a finding.
run_gate() {
    local name="$1"
    shift
    report_status "gate ${name}: $*"
    run "$@" || die "gate ${name} failed ($*): fix the findings above; the tests did not run"
}

cmd_test() {
    WITH_BROWSER=1
    setup_dev test
    cd "${SRCDIR}"
    run_gate ruff "${DEV_VENV}/bin/ruff" check .
    run_gate mypy "${DEV_VENV}/bin/mypy"
    report_status "running the test suite"
    [[ "${DRY_RUN}" == 1 ]] && { run "${DEV_VENV}/bin/python" -m pytest "$@"; return 0; }
    exec "${DEV_VENV}/bin/python" -m pytest "$@"
}

######################################################################
# Service install on the robot (systemd, uninstall, status, logs, health, rollback)
######################################################################

# Fixed locations: the unit file and the daemon's default config path name them.
PREFIX=/opt/arbiterd
CONFIG_DIR=/etc/arbiterd
UNIT_DIR=/etc/systemd/system
UDEV_DIR=/etc/udev/rules.d
SERVICE=arbiterd.service
TARGET=robot.target
SERVICE_USER=arbiterd
STATE_DIR=/var/lib/arbiterd
BIN_LINK=/usr/local/bin/arbiterd
UDEV_RULES="99-rplidar.rules 99-arduino.rules"

ROOT="${ARBITERD_ROOT:-}"                       # staging root ('' = this machine)
SYSTEMCTL="${ARBITERD_SYSTEMCTL:-}"             # systemctl to run ('' = systemctl; staging: none)
HEALTH_TIMEOUT="${ARBITERD_HEALTH_TIMEOUT:-60}" # seconds to wait for /api/health
KEEP_RELEASES="${ARBITERD_KEEP_RELEASES:-5}"    # releases kept under /opt/arbiterd/releases
MODE_FLAG="${ARBITERD_MODE:-}"                  # hardware | sim | '' (keep the current choice)
INSTALL_DRIVER="${ARBITERD_INSTALL_DRIVER:-}"   # [driver] type for a new config
NO_START="${ARBITERD_NO_START:-0}"              # 1 = install only, do not (re)start
PIP_ARGS="${ARBITERD_PIP_ARGS:-}"               # extra pip install arguments
ROS2_FLAG="${ARBITERD_ROS2:-}"                  # 1 | 0 | '' (keep): the ROS 2 face's binding
WHEEL="" RELEASE="" PURGE=0
EXIT_UNHEALTHY=3                                # activated release failed its health check

declare -A PENDING=()    # reload | udev | restart: to do in this run (see pending_load)
START_FAILED=0
declare -A MANIFEST=()   # staging only: path -> "owner:group mode"

staging() { [[ -n "${ROOT}" ]]; }
r() { printf '%s%s' "${ROOT}" "$1"; }       # a system path inside the (staging) root

require_root() {
    staging && return 0
    [[ "${DRY_RUN}" == 1 ]] && return 0
    is_root || die "'./install.sh $1' changes the system and must run as root: sudo ./install.sh $1 ...
       (for a trial run: ./install.sh $1 --dry-run, or --root DIR to lay it out in a staging dir)"
}

# record_action TEXT: note a system change the staging mode does not make (useradd, udevadm...).
record_action() {
    report_status "staging: would run: $*"
    [[ "${DRY_RUN}" == 1 ]] || printf '%s\n' "$*" >>"$(r /.arbiterd-actions)"
}

# own PATH OWNER:GROUP MODE: set the mode; set the owner (or record it, in staging).
own() {
    local path="$1" owner="$2" mode="$3" file
    file="$(r "${path}")"
    if [[ "${mode}" != link && -e "${file}" && ! -L "${file}" \
          && "$(stat -c '%04a' "${file}")" != "${mode}" ]]; then
        run chmod "${mode}" "${file}"
    fi
    if staging; then
        MANIFEST["${path}"]="${owner} $([[ "${mode}" == link ]] && echo link || echo "${mode}")"
    elif [[ "$(stat -c '%U:%G' "${file}" 2>/dev/null)" != "${owner}" ]]; then
        run chown -h "${owner}" "${file}"
    fi
}

ensure_dir() {  # PATH OWNER:GROUP MODE
    [[ -d "$(r "$1")" ]] || run mkdir -p "$(r "$1")"
    own "$@"
}

# put_file SRC DEST OWNER:GROUP MODE: install SRC at DEST when different; returns 0 if changed.
put_file() {
    local src="$1" dest="$2" owner="$3" mode="$4"
    if [[ -f "$(r "${dest}")" ]] && cmp -s "${src}" "$(r "${dest}")"; then
        own "${dest}" "${owner}" "${mode}"
        return 1
    fi
    report_status "installing ${dest}"
    run install -D -m "${mode}" "${src}" "$(r "${dest}")"
    own "${dest}" "${owner}" "${mode}"
    return 0
}

# remove PATH...: delete files or trees inside the root, forgetting them in the manifest.
remove() {
    local path
    for path in "$@"; do
        if [[ -e "$(r "${path}")" || -L "$(r "${path}")" ]]; then
            report_status "removing ${path}"
            run rm -rf -- "$(r "${path}")"
        fi
        local key
        for key in "${!MANIFEST[@]}"; do
            [[ "${key}" == "${path}" || "${key}" == "${path}/"* ]] && unset "MANIFEST[${key}]"
        done
    done
    return 0
}

manifest_load() {
    staging || return 0
    local file path rest
    file="$(r /.arbiterd-manifest)"
    [[ -f "${file}" ]] || return 0
    while IFS=$'\t' read -r path rest; do MANIFEST["${path}"]="${rest}"; done <"${file}"
}

manifest_save() {
    staging && [[ "${DRY_RUN}" != 1 ]] || return 0
    local file path
    file="$(r /.arbiterd-manifest)"
    if (( ${#MANIFEST[@]} == 0 )); then rm -f -- "${file}"; return 0; fi
    for path in "${!MANIFEST[@]}"; do printf '%s\t%s\n' "${path}" "${MANIFEST[${path}]}"; done \
        | LC_ALL=C sort >"${WORKDIR}/manifest"
    cmp -s "${WORKDIR}/manifest" "${file}" || cp "${WORKDIR}/manifest" "${file}"
}

# systemctl_do ARGS...: systemctl on this machine; in staging recorded, and run through
# ARBITERD_SYSTEMCTL when that is set (the deploy test's fake systemd).
systemctl_do() {
    if staging; then
        record_action "systemctl $*"
        [[ -n "${SYSTEMCTL}" ]] || return 0
    fi
    run "${SYSTEMCTL:-systemctl}" "$@"
}

can_start() { ! staging || [[ -n "${SYSTEMCTL}" ]]; }

# py CODE ARGS...: a small Python helper (tomllib needs 3.11, which install checks).
py() { "${PYTHON}" -c "$@"; }

config_path() { r "${CONFIG_DIR}/arbiterd.toml"; }

# config_get SECTION KEY DEFAULT: a value of the installed config, or DEFAULT.
config_get() { config_get_file "$(config_path)" "$@"; }

# config_get_file FILE SECTION KEY DEFAULT: a value of a config file, or DEFAULT.
config_get_file() {
    py 'import sys, tomllib
path, section, key, default = sys.argv[1:5]
try:
    with open(path, "rb") as f:
        data = tomllib.load(f)
except (OSError, tomllib.TOMLDecodeError):
    data = {}
for part in section.split("."):
    data = data.get(part, {})
print(data.get(key, default))' "$@"
}

# toml_set FILE SECTION KEY VALUE: set KEY (TOML literal VALUE) in [SECTION], replacing an
# assignment or a commented-out one, else adding it under the header (or a new section).
toml_set() {
    py 'import re, sys
path, section, key, value = sys.argv[1:5]
lines = open(path, encoding="utf-8").read().splitlines()
header = re.compile(r"^\s*\[([^\]]+)\]\s*$")
assign = re.compile(r"^\s*#?\s*" + re.escape(key) + r"\s*=")
current, start, hit = None, None, None
for i, line in enumerate(lines):
    m = header.match(line)
    if m:
        current = m.group(1).strip()
        if current == section and start is None:
            start = i
    elif current == section and hit is None and assign.match(line):
        hit = i
new = f"{key} = {value}"
if hit is not None:
    lines[hit] = new
elif start is not None:
    lines.insert(start + 1, new)
else:
    lines += ["", f"[{section}]", new]
open(path, "w", encoding="utf-8").write("\n".join(lines) + "\n")' "$@"
}

source_version() {
    py 'import sys, tomllib
print(tomllib.load(open(sys.argv[1], "rb"))["project"]["version"])' "${SRCDIR}/pyproject.toml"
}

# A content hash of the package sources, so re-installing unchanged sources is a no-op.
source_hash() {
    local dirs
    read -r -a dirs <<<"$(source_packages)"
    (cd "${SRCDIR}" && find pyproject.toml "${dirs[@]}" -type f \
        \( -name '*.py' -o -name '*.toml' -o -name '*.json' -o -name 'py.typed' \
           -o -name '*.html' -o -name '*.css' -o -name '*.js' -o -name '*.svg' \) \
        -not -path '*/__pycache__/*' -print0 | LC_ALL=C sort -z | xargs -0 sha256sum) \
        | sha256sum | cut -c1-12
}

# The top-level packages pyproject.toml ships ([tool.setuptools.packages.find] include).
source_packages() {
    py 'import sys, tomllib
find = tomllib.load(open(sys.argv[1], "rb"))["tool"]["setuptools"]["packages"]["find"]
print(" ".join(sorted({name.split(".")[0].rstrip("*") for name in find["include"]})))' \
        "${SRCDIR}/pyproject.toml"
}

# A copy of the package sources to build from, so a root build leaves no files in the clone.
source_snapshot() {
    local dest="${WORKDIR}/src" name
    mkdir -p "${dest}"
    for name in pyproject.toml README.md LICENSE $(source_packages); do
        [[ -e "${SRCDIR}/${name}" ]] || continue
        tar -C "${SRCDIR}" --exclude=__pycache__ --exclude='*.pyc' -cf - "${name}" \
            | tar -C "${dest}" -xf -
    done
    printf '%s' "${dest}"
}

# Step 1: the apt packages the service needs (python venv; pigpiod / lgpio for hardware).
svc_step_packages() {
    local wanted=(python3-venv) driver
    driver="$(effective_driver)"
    if [[ "$(effective_mode)" == hardware ]]; then
        case "${driver}" in
            pigpio) wanted+=(pigpiod) ;;
            l298n) wanted+=(python3-lgpio) ;;
            odrive_can) wanted+=(can-utils) ;;
        esac
    fi
    # the ROS 2 face: pip builds the Cyclone DDS binding against Debian's library
    [[ "$(effective_ros2)" == 1 ]] && wanted+=(cyclonedds-dev gcc python3-dev)
    if staging; then
        record_action "apt-get install ${wanted[*]}"
        return 0
    fi
    local missing=() pkg
    for pkg in "${wanted[@]}"; do
        package_present "${pkg}" || missing+=("${pkg}")
    done
    if (( ${#missing[@]} == 0 )); then
        report_status "system packages: all present"
        return 0
    fi
    for pkg in "${missing[@]}"; do
        apt_offers "${pkg}" && continue
        is_root && [[ "${DRY_RUN}" != 1 ]] && run apt-get update -q >/dev/null
        apt_offers "${pkg}" || not_in_apt "${pkg}"
    done
    apt_install "${missing[@]}"
}

# package_present PKG: installed as a Debian package, or (pigpiod, lgpio) built from source.
package_present() {
    dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q 'ok installed' && return 0
    case "$1" in
        pigpiod) command -v pigpiod >/dev/null 2>&1 ;;
        python3-lgpio) "${PYTHON}" -c 'import importlib.util as u, sys
sys.exit(u.find_spec("lgpio") is None)' 2>/dev/null ;;
        *) return 1 ;;
    esac
}

# apt_offers PKG: this machine's apt sources have a candidate version of PKG.
apt_offers() {
    local candidate
    candidate="$(apt-cache policy "$1" 2>/dev/null | sed -n 's/^ *Candidate: *//p')"
    [[ -n "${candidate}" && "${candidate}" != "(none)" ]]
}

this_system() {
    local name arch
    name="$(. /etc/os-release 2>/dev/null && echo "${PRETTY_NAME:-}")"
    arch="$(dpkg --print-architecture 2>/dev/null || uname -m)"
    printf '%s (%s)' "${name:-this system}" "${arch}"
}

# not_in_apt PKG: say where a package missing from apt comes from and what to do instead.
not_in_apt() {
    local others="or pick a driver that needs no GPIO package: --driver serial (an Arduino with ROSArduinoBridge) or --driver odrive_can"
    case "$1" in
        pigpiod) die "apt has no package pigpiod on $(this_system).
  pigpiod, the GPIO daemon of the pigpio driver, is packaged by Raspberry Pi OS in its own
  apt repository, not by Debian: this machine is not Raspberry Pi OS or lacks that repository.
  What to do instead: install Raspberry Pi OS Bookworm (what the robot steps assume);
  or build pigpio from source (github.com/joan2937/pigpio: make && sudo make install, then
  install its util/pigpiod.service as /etc/systemd/system/pigpiod.service) and re-run this
  command, which then finds /usr/local/bin/pigpiod;
  ${others}. (pigpio does not run on a Pi 5.)" ;;
        python3-lgpio) die "apt has no package python3-lgpio on $(this_system).
  lgpio, the GPIO library of the l298n driver (gpiozero's lgpio pin factory), is packaged by
  Raspberry Pi OS in its own apt repository, not by Debian 12: this machine is not Raspberry
  Pi OS or lacks that repository.
  What to do instead: install Raspberry Pi OS Bookworm (what the robot steps assume);
  or build lg and its Python module from source (github.com/joan2937/lg) for ${PYTHON},
  create a 'gpio' group owning /dev/gpiochip* (a udev rule), and re-run this command, which
  then finds the module;
  ${others}." ;;
        *) die "apt has no package $1 on $(this_system); run 'sudo apt-get update' and retry" ;;
    esac
}

# Step 2: the system user, in the device groups that exist on this machine; then verified.
svc_step_user() {
    local groups=() group
    if staging; then
        record_action "ensure system user ${SERVICE_USER} (home ${STATE_DIR}) in groups gpio dialout (+ i2c spi if present)"
        record_action "verify ${SERVICE_USER} is in groups: $(needed_groups)"
        return 0
    fi
    if ! id -u "${SERVICE_USER}" >/dev/null 2>&1; then
        report_status "creating system user ${SERVICE_USER}"
        run useradd --system --user-group --no-create-home --home-dir "${STATE_DIR}" \
            --shell /usr/sbin/nologin --comment "arbiterd robot daemon" "${SERVICE_USER}"
    fi
    for group in gpio dialout i2c spi; do
        if getent group "${group}" >/dev/null; then groups+=("${group}")
        elif [[ "${group}" == gpio || "${group}" == dialout ]]; then
            warn "group ${group} does not exist here (not a Raspberry Pi OS image?)"
        fi
    done
    (( ${#groups[@]} == 0 )) || run usermod --append --groups "$(IFS=,; echo "${groups[*]}")" \
        "${SERVICE_USER}"
    verify_groups
}

# The groups the service user must be in: dialout (serial: Arduino, lidar, UARTs) always;
# gpio (/dev/gpiochip*, /dev/gpiomem) for a GPIO driver on the hardware.
needed_groups() {
    local need=dialout
    [[ "$(effective_mode)" == hardware && "$(effective_driver)" == l298n ]] && need+=" gpio"
    echo "${need}"
}

verify_groups() {
    local have missing=() group
    if [[ "${DRY_RUN}" == 1 ]]; then
        report_status "would verify ${SERVICE_USER} is in groups: $(needed_groups)"
        return 0
    fi
    have=" $(id -nG "${SERVICE_USER}") "
    for group in $(needed_groups); do
        [[ "${have}" == *" ${group} "* ]] || missing+=("${group}")
    done
    (( ${#missing[@]} == 0 )) || die "the service user ${SERVICE_USER} is not in group(s) ${missing[*]}, so it cannot open the robot's devices.
  On Raspberry Pi OS these groups own the serial ports (dialout) and the GPIO chips (gpio).
  Create the missing group(s) and a udev rule giving them the devices (groupadd --system NAME),
  then re-run this command; it adds ${SERVICE_USER} to them."
    report_status "service user ${SERVICE_USER}: groups${have% }"
}

# Step 3: the release: a venv (with the system site packages, for apt's lgpio/pigpio) holding
# the package, under /opt/arbiterd/releases/NAME, plus this installer and the unit files.
svc_step_release() {
    local id reldir ros2 extra=""
    ros2="$(effective_ros2)"
    [[ "${ros2}" == 1 ]] && extra="-ros2"
    if [[ -n "${WHEEL}" ]]; then
        [[ -f "${WHEEL}" ]] || die "--wheel ${WHEEL}: no such file"
        id="wheel:$(sha256_of "${WHEEL}")${extra}"
        [[ -n "${RELEASE}" ]] || RELEASE="$(basename "${WHEEL}" | cut -d- -f2)-$(sha256_of "${WHEEL}" | cut -c1-12)${extra}"
    else
        id="source:$(source_hash)${extra}"
        [[ -n "${RELEASE}" ]] || RELEASE="$(source_version)-$(source_hash)${extra}"
    fi
    [[ "${RELEASE}" =~ ^[A-Za-z0-9][A-Za-z0-9._+-]*$ ]] || die "invalid release name: ${RELEASE}"
    reldir="${PREFIX}/releases/${RELEASE}"
    ensure_dir "${PREFIX}" root:root 0755
    ensure_dir "${PREFIX}/releases" root:root 0755
    ensure_dir "${reldir}" root:root 0755
    if [[ -x "$(r "${reldir}")/venv/bin/arbiterd" && -f "$(r "${reldir}")/.release-id" \
          && "$(cat "$(r "${reldir}")/.release-id")" == "${id}" ]]; then
        report_status "release ${RELEASE}: already installed"
        return 0
    fi
    report_status "installing release ${RELEASE}"
    copy_installer_into "${reldir}"
    run rm -rf -- "$(r "${reldir}")/venv"
    run "${PYTHON}" -m venv --system-site-packages "$(r "${reldir}")/venv"
    local index=()
    if [[ -d "$(r "${reldir}")/wheels" ]]; then   # a shipped wheelhouse: install offline
        index+=(--no-index --find-links "$(r "${reldir}")/wheels")
    fi
    # shellcheck disable=SC2206  # PIP_ARGS is a list of words on purpose
    index+=(${PIP_ARGS})
    venv_bootstrap "$(r "${reldir}")/venv/bin/python" "${index[@]}"
    # the ros2 extra: pip builds the Cyclone DDS binding against Debian's library (docs/ros2.md)
    local build_env=()
    [[ -z "${extra}" ]] || build_env=(CYCLONEDDS_HOME="$(cyclonedds_home "$(r "${reldir}")")")
    run env "${build_env[@]}" "$(r "${reldir}")/venv/bin/python" -m pip install -q --disable-pip-version-check \
        "${index[@]}" "${WHEEL:-$(source_snapshot)}${extra:+[ros2]}"
    if [[ "${DRY_RUN}" != 1 ]]; then
        printf '%s\n' "${id}" >"$(r "${reldir}")/.release-id"
        if [[ -n "${extra}" ]]; then : >"$(r "${reldir}")/.ros2"; else rm -f "$(r "${reldir}")/.ros2"; fi
    fi
    pending_add restart
}

# The release keeps the installer and units it was installed with (used by rollback).
copy_installer_into() {
    local dest
    dest="$(r "$1")"
    [[ "$(cd "${SRCDIR}" && pwd -P)" == "$(cd "${dest}" 2>/dev/null && pwd -P)" ]] && return 0
    run install -m 0755 "${SRCDIR}/install.sh" "${dest}/install.sh"
    run mkdir -p "${dest}/systemd"
    run cp -p "${SRCDIR}"/systemd/* "${dest}/systemd/"
}

history_file() { r "${PREFIX}/history"; }

# activate NAME: point /opt/arbiterd/current at releases/NAME atomically; remember the order.
activate() {
    local name="$1" link tmp
    link="$(r "${PREFIX}/current")"
    [[ -d "$(r "${PREFIX}/releases/${name}")" || "${DRY_RUN}" == 1 ]] \
        || die "no release ${name} in ${PREFIX}/releases"
    if [[ "$(readlink "${link}" 2>/dev/null)" == "releases/${name}" ]]; then
        report_status "current release: ${name} (unchanged)"
    else
        report_status "switching ${PREFIX}/current to ${name}"
        tmp="${link}.new.$$"
        run ln -sfn "releases/${name}" "${tmp}"
        run mv -Tf "${tmp}" "${link}"
        pending_add restart
    fi
    own "${PREFIX}/current" root:root link
    if [[ "$(tail -n 1 "$(history_file)" 2>/dev/null)" != "${name}" ]]; then
        [[ "${DRY_RUN}" == 1 ]] || printf '%s\n' "${name}" >>"$(history_file)"
    fi
    [[ -f "$(history_file)" ]] && own "${PREFIX}/history" root:root 0644
    return 0
}

svc_step_activate() { activate "${RELEASE}"; }

effective_mode() {
    if [[ -n "${MODE_FLAG}" ]]; then echo "${MODE_FLAG}"
    elif [[ -f "$(r "${CONFIG_DIR}/arbiterd.env")" ]] \
         && grep -q '^ARBITERD_ARGS=$' "$(r "${CONFIG_DIR}/arbiterd.env")"; then echo hardware
    else echo sim; fi
}

# effective_ros2: 1 when the release gets the ROS 2 face's binding (--ros2, or the current
# release has it, marked by its .ros2 file, and no --no-ros2), else 0.
effective_ros2() {
    if [[ -n "${ROS2_FLAG}" ]]; then echo "${ROS2_FLAG}"
    elif [[ -e "$(r "${PREFIX}/current/.ros2")" ]]; then echo 1
    else echo 0; fi
}

effective_driver() {
    if [[ -f "$(config_path)" ]]; then config_get driver type mock
    else echo "${INSTALL_DRIVER:-mock}"; fi
}

# Step 4: /etc/arbiterd: the config (never overwritten), the control token (created once,
# printed once) and the environment file that picks hardware or simulation.
svc_step_config() {
    ensure_dir "${CONFIG_DIR}" "root:${SERVICE_USER}" 0750
    write_config
    write_token
    write_env_file
}

write_config() {
    local dest="${CONFIG_DIR}/arbiterd.toml" tmp="${WORKDIR}/arbiterd.toml"
    if [[ -f "$(r "${dest}")" ]]; then
        report_status "keeping existing ${dest}"
        if [[ -n "${INSTALL_DRIVER}" && "$(config_get driver type mock)" != "${INSTALL_DRIVER}" ]]; then
            warn "--driver ${INSTALL_DRIVER} ignored: ${dest} already sets [driver] type = $(config_get driver type mock); edit it by hand"
        fi
        own "${dest}" "root:${SERVICE_USER}" 0640
    else
        if [[ -f "${SRCDIR}/systemd/arbiterd.toml.example" ]]; then
            cp "${SRCDIR}/systemd/arbiterd.toml.example" "${tmp}"
        else
            printf '# arbiterd configuration (written by install.sh)\n' >"${tmp}"
        fi
        [[ -z "${INSTALL_DRIVER}" ]] || toml_set "${tmp}" driver type "\"${INSTALL_DRIVER}\""
        # the serial board at the udev rule's stable name (99-arduino.rules)
        [[ "$(config_get_file "${tmp}" driver type mock)" != serial ]] \
            || toml_set "${tmp}" driver.serial port '"/dev/arduino"'
        toml_set "${tmp}" security token_file "\"${CONFIG_DIR}/token\""
        put_file "${tmp}" "${dest}" "root:${SERVICE_USER}" 0640 || true
        pending_add restart
    fi
}

write_token() {
    local dest="${CONFIG_DIR}/token" tmp="${WORKDIR}/token" token
    if [[ -f "$(r "${dest}")" ]]; then
        own "${dest}" "root:${SERVICE_USER}" 0640
        return 0
    fi
    token="$(py 'import secrets; print(secrets.token_urlsafe(32))')"
    (umask 077 && printf '%s\n' "${token}" >"${tmp}")
    put_file "${tmp}" "${dest}" "root:${SERVICE_USER}" 0640 || true
    rm -f -- "${tmp}"
    [[ "${DRY_RUN}" == 1 ]] && return 0
    printf '\n%s: control token (shown once; kept in %s):\n    %s\n\n' "${PROG}" "${dest}" "${token}"
}

write_env_file() {
    local dest="${CONFIG_DIR}/arbiterd.env" tmp="${WORKDIR}/arbiterd.env" args="--sim" mode
    mode="$(effective_mode)"
    [[ "${mode}" == hardware ]] && args=""
    {
        printf '# Written by install.sh: "sim" runs the simulated robot, "hardware" the real one.\n'
        printf '# Change it with: sudo ./install.sh systemd --hardware (or --sim)\n'
        printf 'ARBITERD_ARGS=%s\n' "${args}"
    } >"${tmp}"
    if put_file "${tmp}" "${CONFIG_DIR}/arbiterd.env" root:root 0644; then pending_add restart; fi
    report_status "service mode: ${mode}"
}

# Step 5: the units, the pigpiod drop-ins (pigpio driver on hardware only), the udev rules and
# the `arbiterd` command on every user's PATH.
svc_step_units() {
    local unit dropin rules
    for unit in "${SERVICE}" "${TARGET}"; do
        if put_file "${SRCDIR}/systemd/${unit}" "${UNIT_DIR}/${unit}" root:root 0644; then
            pending_add reload restart
        fi
    done
    for dropin in "${SERVICE}.d" "${TARGET}.d"; do
        if [[ "$(effective_mode)" == hardware && "$(effective_driver)" == pigpio ]]; then
            ensure_dir "${UNIT_DIR}/${dropin}" root:root 0755
            if put_file "${SRCDIR}/systemd/pigpiod.conf" "${UNIT_DIR}/${dropin}/pigpiod.conf" \
                   root:root 0644; then pending_add reload restart; fi
        elif [[ -e "$(r "${UNIT_DIR}/${dropin}/pigpiod.conf")" ]]; then
            remove "${UNIT_DIR}/${dropin}/pigpiod.conf"
            run rmdir --ignore-fail-on-non-empty "$(r "${UNIT_DIR}/${dropin}")"
            pending_add reload restart
        fi
    done
    for rules in ${UDEV_RULES}; do
        if put_file "${SRCDIR}/systemd/${rules}" "${UDEV_DIR}/${rules}" root:root 0644; then
            pending_add udev
        fi
    done
    command_link
}

# /usr/local/bin/arbiterd -> the current release's command (relative, so a staging root works).
command_link() {
    local link target="../../..${PREFIX}/current/venv/bin/arbiterd"
    link="$(r "${BIN_LINK}")"
    if [[ -e "${link}" && ! -L "${link}" ]]; then
        warn "${BIN_LINK} exists and is not a link to arbiterd: left alone (use ${PREFIX}/current/venv/bin/arbiterd)"
        return 0
    fi
    if [[ "$(readlink "${link}" 2>/dev/null)" != "${target}" ]]; then
        report_status "linking ${BIN_LINK} -> ${PREFIX}/current/venv/bin/arbiterd"
        run mkdir -p "$(dirname "${link}")"
        run ln -sfn "${target}" "${link}"
    fi
    own "${BIN_LINK}" root:root link
}

# Work that must still happen although a later run sees nothing changed: a daemon-reload, a
# udev reload or a restart that a failed run left undone. Kept in PENDING_FILE until done.
pending_file() { r "${PREFIX}/.pending"; }

pending_load() {
    local what
    [[ -f "$(pending_file)" ]] || return 0
    for what in $(cat "$(pending_file)"); do PENDING[${what}]=1; done
    report_status "finishing what an earlier run left undone: ${!PENDING[*]}"
}

pending_add() {
    local what
    for what in "$@"; do PENDING[${what}]=1; done
    pending_save
}

pending_done() {
    unset "PENDING[$1]"
    pending_save
}

pending_save() {
    [[ "${DRY_RUN}" != 1 && -d "$(r "${PREFIX}")" ]] || return 0
    if (( ${#PENDING[@]} )); then echo "${!PENDING[*]}" >"$(pending_file)"
    else rm -f -- "$(pending_file)"; fi
}

pending() { [[ -n "${PENDING[$1]:-}" ]]; }

# Step 6: tell systemd and udev, enable at boot, (re)start when anything changed.
svc_step_enable() {
    if pending reload; then
        systemctl_do daemon-reload || die "systemctl daemon-reload failed; fix the cause and re-run this command (it will reload then)"
        pending_done reload
    fi
    if pending udev; then
        if staging; then record_action "udevadm control --reload; udevadm trigger --subsystem-match=tty"
        else run udevadm control --reload && run udevadm trigger --subsystem-match=tty --action=add \
            || die "udevadm could not reload the rules; re-run this command once udev runs"
        fi
        pending_done udev
    fi
    if [[ "$(effective_mode)" == hardware && "$(effective_driver)" == pigpio ]]; then
        systemctl_do enable --now pigpiod.service
    fi
    systemctl_do enable "${SERVICE}" "${TARGET}"
    if [[ "${NO_START}" == 1 ]]; then
        report_status "not starting the service (--no-start)"
        pending_done restart
    elif pending restart; then
        systemctl_do restart "${SERVICE}" || START_FAILED=1
        pending_done restart
    else
        systemctl_do start "${SERVICE}" || START_FAILED=1
    fi
}

# Step 7: wait for /api/health; on failure say why (exit 3: the release is active but unhealthy).
svc_step_health() {
    if [[ "${NO_START}" == 1 ]]; then
        print_next_steps
        return 0
    fi
    if ! can_start || [[ "${DRY_RUN}" == 1 ]]; then
        staging && report_status "staging root: service not started, health not checked"
        return 0
    fi
    if (( START_FAILED )); then
        report_status "${SERVICE} failed to start"
        report_failure
        exit "${EXIT_UNHEALTHY}"
    fi
    if ! wait_health; then
        report_failure
        exit "${EXIT_UNHEALTHY}"
    fi
    print_connect_info
}

# After --no-start: what the admin runs next, in order (README "On the robot").
print_next_steps() {
    report_status "installed, not started. Next:"
    printf '    sudoedit %s/arbiterd.toml   # ports, pins, wheel geometry\n' "${CONFIG_DIR}"
    printf '    sudo arbiterd check                    # verdict first; exit 0 = ready\n'
    printf '    sudo systemctl enable --now %s   # start now and at every boot\n' "${TARGET}"
}

health_url() {
    local host port
    port="$(config_get http port 8085)"
    host="$(config_get http host 0.0.0.0)"
    case "${host}" in 0.0.0.0|""|::|"[::]") host=127.0.0.1 ;; esac
    printf 'http://%s:%s/api/health' "${host}" "${port}"
}

# Prints the health "status" field (ok/degraded/error), or nothing when unreachable.
fetch_health() {
    py 'import json, sys, urllib.error, urllib.request
try:
    with urllib.request.urlopen(sys.argv[1], timeout=2) as r:
        body = json.load(r)
except urllib.error.HTTPError as e:
    body = json.load(e)
except (OSError, ValueError):
    sys.exit(1)
print(body.get("status", "?"))' "$1" 2>/dev/null
}

service_failed() { "${SYSTEMCTL:-systemctl}" is-failed --quiet "${SERVICE}" 2>/dev/null; }

# A component still starting (the lidar before its first revolution) reads "degraded": give it
# DEGRADED_GRACE seconds to become ok, then accept degraded with a warning.
wait_health() {
    local url status="" deadline=$((SECONDS + HEALTH_TIMEOUT)) degraded_since=""
    url="$(health_url)"
    report_status "waiting up to ${HEALTH_TIMEOUT}s for ${url}"
    while (( SECONDS < deadline )); do
        status="$(fetch_health "${url}" || true)"
        case "${status}" in
            ok) report_status "health: ok"; return 0 ;;
            degraded)
                degraded_since="${degraded_since:-${SECONDS}}"
                if (( SECONDS - degraded_since >= ${DEGRADED_GRACE:-10} )); then
                    warn "health: degraded (running; see ./install.sh status)"
                    return 0
                fi ;;
        esac
        if service_failed; then
            report_status "${SERVICE} failed while starting"
            return 1
        fi
        sleep 0.5
    done
    report_status "no healthy answer from ${url} within ${HEALTH_TIMEOUT}s (last: ${status:-none})"
    return 1
}

report_failure() {
    printf '%s: error: %s is not healthy; its state and last log lines:\n' "${PROG}" "${SERVICE}" >&2
    "${SYSTEMCTL:-systemctl}" status --no-pager --lines=30 "${SERVICE}" >&2 || true
    staging || journalctl -u "${SERVICE}" -n 30 --no-pager >&2 || true
}

print_connect_info() {
    local addr port ws
    addr="$(hostname -I 2>/dev/null | awk '{print $1}')"
    port="$(config_get http port 8085)"
    ws="$(config_get rosbridge port 9090)"
    report_status "arbiterd is running. Connect to:"
    printf '    console   http://%s:%s/\n' "${addr:-<robot-ip>}" "${port}"
    printf '    HTTP      http://%s:%s/api/health\n' "${addr:-<robot-ip>}" "${port}"
    printf '    rosbridge ws://%s:%s   (token: %s/token, send as Bearer or ?token=)\n' \
        "${addr:-<robot-ip>}" "${ws}" "${CONFIG_DIR}"
}

# Keep the newest KEEP_RELEASES of the activation history (and always the current one).
svc_step_prune() {
    local keep=() name dir current
    current="$(basename "$(readlink "$(r "${PREFIX}/current")" 2>/dev/null || echo none)")"
    [[ -f "$(history_file)" ]] && mapfile -t keep < <(tac "$(history_file)" | awk '!seen[$0]++' \
        | head -n "${KEEP_RELEASES}")
    keep+=("${current}" "${RELEASE}")
    for dir in "$(r "${PREFIX}/releases")"/*/; do
        [[ -d "${dir}" ]] || continue
        name="$(basename "${dir}")"
        printf '%s\n' "${keep[@]}" | grep -qxF -- "${name}" && continue
        report_status "pruning old release ${name}"
        remove "${PREFIX}/releases/${name}"
    done
}

cmd_systemd() {
    require_root systemd
    check_python
    manifest_load
    pending_load
    svc_step_packages
    svc_step_user
    svc_step_config
    svc_step_release
    svc_step_activate
    svc_step_units
    svc_step_enable
    manifest_save
    svc_step_prune
    manifest_save
    svc_step_health
    report_status "installed release ${RELEASE}$(staging && printf ' into staging root %s' "${ROOT}")"
}

# Roll back to the release activated before the current one (the history is a stack).
cmd_rollback() {
    require_root rollback
    check_python
    manifest_load
    pending_load
    local hist current previous
    hist="$(history_file)"
    [[ -f "${hist}" ]] || die "no release history in ${PREFIX}: nothing to roll back to"
    current="$(basename "$(readlink "$(r "${PREFIX}/current")" 2>/dev/null || echo none)")"
    previous="$(grep -vxF -- "${current}" "${hist}" | tail -n 1 || true)"
    [[ -n "${previous}" ]] || die "no release before ${current}: nothing to roll back to"
    report_status "rolling back from ${current} to ${previous}"
    RELEASE="${previous}"
    if [[ "${DRY_RUN}" != 1 ]]; then   # pop the current release off the history
        grep -vxF -- "${current}" "${hist}" >"${hist}.new" || true
        mv -f "${hist}.new" "${hist}"
    fi
    activate "${previous}"
    pending_add restart
    svc_step_enable
    manifest_save
    svc_step_health
    report_status "rolled back to ${previous}"
}

cmd_uninstall() {
    require_root uninstall
    manifest_load
    systemctl_do disable --now "${SERVICE}" "${TARGET}" || warn "could not disable ${SERVICE}"
    local rules
    remove "${UNIT_DIR}/${SERVICE}" "${UNIT_DIR}/${TARGET}" "${UNIT_DIR}/${SERVICE}.d" \
        "${UNIT_DIR}/${TARGET}.d" "${PREFIX}"
    for rules in ${UDEV_RULES}; do remove "${UDEV_DIR}/${rules}"; done
    [[ ! -L "$(r "${BIN_LINK}")" ]] || remove "${BIN_LINK}"
    systemctl_do daemon-reload || true
    if staging; then record_action "udevadm control --reload"
    else run udevadm control --reload || true; fi
    if (( PURGE )); then
        remove "${CONFIG_DIR}" "${STATE_DIR}"
        if staging; then record_action "userdel ${SERVICE_USER}"
        elif id -u "${SERVICE_USER}" >/dev/null 2>&1; then run userdel "${SERVICE_USER}"; fi
    else
        report_status "keeping ${CONFIG_DIR} (config and token); --purge removes it"
    fi
    manifest_save
    report_status "uninstalled"
}

cmd_status() {
    local url
    url="$(health_url)"
    "${SYSTEMCTL:-systemctl}" status --no-pager --lines=0 "${SERVICE}" || true
    if [[ -x "$(r "${PREFIX}/current/venv/bin/arbiterd")" ]]; then
        "$(r "${PREFIX}/current/venv/bin/arbiterd")" status --url "${url%/api/health}"
    else
        printf 'health: %s\n' "$(fetch_health "${url}" || echo unreachable)"
    fi
}

cmd_logs() { exec journalctl -u "${SERVICE}" --no-pager -n 200 "$@"; }

cmd_health() { wait_health; }

######################################################################
# Entry point
######################################################################

usage() {
    cat <<EOF
usage: ./install.sh COMMAND [OPTIONS]

Developer commands (run from a clone, as a normal user; apt packages go through sudo):
  dev                  set up .venv (package editable + test/dev/bench extras) and the test
                       tools (apt packages, npm ci for the JavaScript test clients in
                       tests/interop and tests/console)
  sim [ARGS...]        set up .venv with what running needs only, then run
                       'arbiterd run --sim ARGS...' in the foreground
                       (the console is at http://localhost:8085/)
  test [ARGS...]       dev plus Debian's chromium (browser tests), then the gates 'ruff check .'
                       and 'mypy' (a finding stops here), then 'python -m pytest ARGS...'

Robot commands (Raspberry Pi OS Bookworm / Debian 12, as root):
  systemd              install or update the service: apt packages, user 'arbiterd', a release
                       venv under /opt/arbiterd, /etc/arbiterd/{arbiterd.toml,token,arbiterd.env},
                       units, udev rules (/dev/rplidar, /dev/arduino), /usr/local/bin/arbiterd;
                       enable, (re)start, wait for /api/health
  uninstall            stop and remove it all; keeps /etc/arbiterd unless --purge
  rollback             switch back to the previously activated release and restart it
  status               service state, health and latency
  logs [ARGS...]       journal of the service (journalctl ARGS, e.g. -f)
  health               wait for /api/health to answer ok (exit 0) or give up (exit 1)

Options:
  --hardware | --sim   run the real robot / the simulated one (default: keep; first install: sim)
  --driver NAME        [driver] type for a new config: ${DRIVERS}
                       (serial: an Arduino with ROSArduinoBridge, at /dev/arduino)
  --wheel FILE         install this wheel instead of building the source tree
  --ros2 | --no-ros2   with / without the ROS 2 face's Cyclone DDS binding (apt cyclonedds-dev,
                       pip cyclonedds built against it; docs/ros2.md) (default: keep; first: without)
  --release NAME       name of the release directory (default: version + content hash)
  --keep N             releases to keep (default ${KEEP_RELEASES})
  --health-timeout S   seconds to wait for /api/health (default ${HEALTH_TIMEOUT})
  -z, --no-start       install only; do not start or restart the service
  --purge              uninstall: also remove /etc/arbiterd, the state dir and the user
  --root DIR           lay everything out under DIR (a staging root): no useradd/chown/systemctl;
                       owners and modes go to DIR/.arbiterd-manifest, system actions to
                       DIR/.arbiterd-actions
  --dry-run            print every action instead of doing it
  -h, --help           this help

Environment (same as the flags): ARBITERD_ROOT, ARBITERD_DRY_RUN=1, ARBITERD_MODE=hardware|sim,
ARBITERD_INSTALL_DRIVER, ARBITERD_ROS2=1|0, ARBITERD_NO_START=1, ARBITERD_KEEP_RELEASES, ARBITERD_HEALTH_TIMEOUT;
also ARBITERD_PYTHON (dev: python3; robot: /usr/bin/python3), ARBITERD_PIP_ARGS (extra pip arguments), ARBITERD_SYSTEMCTL
(systemctl to call; with --root it is only recorded unless this is set), ARBITERD_DEV_VENV.
Exit status: 0 ok, 1 error, 2 usage, 3 the new release is active but failed its health check.
EOF
}

usage_error() { printf '%s: error: %s (see ./install.sh --help)\n' "${PROG}" "$*" >&2; exit 2; }

DRIVERS="mock l298n pigpio serial odrive_can"

need_value() { (( $1 > 1 )) || usage_error "$2 needs a value"; }

# parse_service_options ARGS...: the flags of the robot commands.
parse_service_options() {
    while (( $# )); do
        case "$1" in
            --root) need_value $# "$1"; ROOT="$2"; shift ;;
            --root=*) ROOT="${1#*=}" ;;
            --dry-run) DRY_RUN=1 ;;
            --hardware) MODE_FLAG=hardware ;;
            --sim) MODE_FLAG=sim ;;
            --driver) need_value $# "$1"; INSTALL_DRIVER="$2"; shift ;;
            --wheel) need_value $# "$1"; WHEEL="$2"; shift ;;
            --ros2) ROS2_FLAG=1 ;;
            --no-ros2) ROS2_FLAG=0 ;;
            --release) need_value $# "$1"; RELEASE="$2"; shift ;;
            --keep) need_value $# "$1"; KEEP_RELEASES="$2"; shift ;;
            --health-timeout|--timeout) need_value $# "$1"; HEALTH_TIMEOUT="$2"; shift ;;
            -z|--no-start) NO_START=1 ;;
            --purge) PURGE=1 ;;
            -h|--help) usage; exit 0 ;;
            *) usage_error "unknown option: $1" ;;
        esac
        shift
    done
    validate_service_options
}

validate_service_options() {
    [[ -z "${INSTALL_DRIVER}" || " ${DRIVERS} " == *" ${INSTALL_DRIVER} "* ]] \
        || usage_error "--driver ${INSTALL_DRIVER}: not one of: ${DRIVERS}"
    [[ -z "${MODE_FLAG}" || "${MODE_FLAG}" == hardware || "${MODE_FLAG}" == sim ]] \
        || usage_error "ARBITERD_MODE=${MODE_FLAG}: use hardware or sim"
    [[ -z "${ROS2_FLAG}" || "${ROS2_FLAG}" == 1 || "${ROS2_FLAG}" == 0 ]] \
        || usage_error "ARBITERD_ROS2=${ROS2_FLAG}: use 1 (with the ROS 2 face) or 0"
    if ! [[ "${KEEP_RELEASES}" =~ ^[0-9]+$ ]] || (( KEEP_RELEASES < 2 )); then
        usage_error "--keep ${KEEP_RELEASES}: need a number >= 2 (the rollback target is kept)"
    fi
    [[ "${HEALTH_TIMEOUT}" =~ ^[0-9]+$ ]] \
        || usage_error "--health-timeout ${HEALTH_TIMEOUT}: not a number of seconds"
    [[ -z "${WHEEL}" ]] || WHEEL="$(realpath -- "${WHEEL}")"
    if [[ -n "${ROOT}" ]]; then
        ROOT="$(realpath -m -- "${ROOT}")"
        [[ "${ROOT}" != / ]] || ROOT=""
    fi
    return 0
}

# Per-run scratch space, and (staging) a fresh log of the system actions this run records.
prepare_service_run() {
    # The service's venv sees the system site packages (apt's lgpio, pigpio): it must be made by
    # the system's own Python, whatever python3 a login shell finds first.
    [[ -n "${ARBITERD_PYTHON:-}" || ! -x /usr/bin/python3 ]] || PYTHON=/usr/bin/python3
    WORKDIR="$(mktemp -d)"
    trap 'rm -rf -- "${WORKDIR}"' EXIT
    if staging && [[ "${DRY_RUN}" != 1 ]]; then
        mkdir -p -- "${ROOT}"
        : >"$(r /.arbiterd-actions)"
    fi
}

main() {
    local cmd="${1:-}"
    [[ -n "${cmd}" ]] || { usage >&2; exit 2; }
    shift
    case "${cmd}" in
        -h|--help|help) usage ;;
        dev)
            while (( $# )); do
                case "$1" in
                    --dry-run) DRY_RUN=1 ;;
                    -h|--help) usage; return 0 ;;
                    *) usage_error "unknown option for dev: $1" ;;
                esac
                shift
            done
            cmd_dev ;;
        sim) cmd_sim "$@" ;;
        test) cmd_test "$@" ;;
        logs) cmd_logs "$@" ;;
        systemd|uninstall|rollback|status|health)
            parse_service_options "$@"
            prepare_service_run
            "cmd_${cmd}" ;;
        *) usage_error "unknown command '${cmd}'" ;;
    esac
}

main "$@"
