# Shared by deploy/*.sh (sourced, not run): system packages, arm64 emulation, podman options.

# ensure_packages CMD=PACKAGE ...: apt-get install the packages whose command is missing (needs root).
ensure_packages() {
    local missing=() pair
    for pair in "$@"; do
        command -v "${pair%%=*}" >/dev/null 2>&1 || missing+=("${pair#*=}")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    if [ "$(id -u)" != 0 ]; then
        echo "missing ${missing[*]}: install them (apt-get install ${missing[*]}) or run as root" >&2
        return 2
    fi
    echo "installing ${missing[*]}"
    apt-get update -q
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${missing[@]}"
}

# ensure_binfmt_aarch64: arm64 binaries run through qemu-user (binfmt_misc mounted, qemu-aarch64 registered).
ensure_binfmt_aarch64() {
    [ "$(uname -m)" = aarch64 ] && return 0
    ensure_packages qemu-aarch64-static=qemu-user-static || return
    local binfmt=/proc/sys/fs/binfmt_misc
    mountpoint -q "$binfmt" || mount -t binfmt_misc binfmt_misc "$binfmt"
    if [ ! -e "$binfmt/qemu-aarch64" ]; then
        # the F flag (in Debian's entry): the interpreter is opened now, so it works in chroots and containers
        grep -v '^#' /usr/lib/binfmt.d/qemu-aarch64.conf > "$binfmt/register"
    fi
    grep -q '^enabled' "$binfmt/qemu-aarch64" || { echo "the qemu-aarch64 binfmt_misc entry is disabled" >&2; return 1; }
}

# podman_limits: --ulimit options for machines whose hard limits are below podman's defaults (rootful
# podman asks for nofile 1048576 and an nproc above them; a container then fails to start). nproc: 4096
# (as many threads as the daemon could ever want; the machine's own hard limit was refused by runc here).
podman_limits() {
    local nofile nproc
    nofile="$(ulimit -Hn)" nproc="$(ulimit -Hu)"
    [ "$nofile" != unlimited ] && [ "$nofile" -lt 1048576 ] && printf -- '--ulimit nofile=%s:%s ' "$nofile" "$nofile"
    [ "$nproc" != unlimited ] && [ "$nproc" -lt 4194304 ] && printf -- '--ulimit nproc=4096:4096 '
    return 0
}

# trust_files: this machine's CA bundle and pip configuration when they differ from a stock Debian's
# (a TLS-intercepting proxy's CA added under /usr/local/share/ca-certificates, a pip.conf naming it):
# builds and the arm64 root file system use them for pip's downloads, as a Pi on that network would.
trust_files() {
    local bundle=/etc/ssl/certs/ca-certificates.crt
    if [ -f "$bundle" ] && compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null; then echo "$bundle"; fi
    [ -f /etc/pip.conf ] && echo /etc/pip.conf
    return 0
}
