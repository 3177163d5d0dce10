#!/usr/bin/env bash
# Debian packages the test suite starts for real: PostgreSQL (a throwaway cluster per test session) and
# Chromium (the report and screen tests drive it through playwright).  Installed only when missing.
#
# Why a script: another apt-get or dpkg (an unattended upgrade, a second terminal) holding the package
# manager's lock made the README's test command exit 100 on its first try.  apt-get waits for the dpkg
# lock when told (DPkg::Lock::Timeout), but `apt-get update` does not wait for its lists lock, so each
# step is tried again while the lock is held, up to WAIT_S, and what failed is said if it still does.
set -uo pipefail

export DEBIAN_FRONTEND=noninteractive
WAIT_S="${MAGLINE_APT_WAIT_S:-600}"
PACKAGES=(postgresql chromium)

have_all() {
  ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 && command -v chromium >/dev/null
}

# run "$@" until it succeeds, or fails for a reason other than a held lock, or WAIT_S has passed
with_lock_wait() {
  local what="$1"; shift
  local deadline=$(( $(date +%s) + WAIT_S )) output status
  while true; do
    output="$("$@" 2>&1)"; status=$?
    if [ "$status" -eq 0 ]; then return 0; fi
    if ! grep -qiE "could not get lock|unable to (acquire|lock)" <<<"$output" || [ "$(date +%s)" -ge "$deadline" ]; then
      echo "system packages: $what failed (exit $status) while installing ${PACKAGES[*]}:" >&2
      grep -E "^(E|W):" <<<"$output" | tail -5 >&2
      if grep -qiE "could not get lock" <<<"$output"; then
        echo "another package manager still held the lock after ${WAIT_S} s: let it finish, then run this again" >&2
      fi
      return "$status"
    fi
    echo "system packages: the package manager is busy (another apt-get or dpkg); waiting for it…" >&2
    sleep 5
  done
}

have_all && exit 0
with_lock_wait "apt-get update" apt-get -qq -o DPkg::Lock::Timeout=60 update || exit
with_lock_wait "apt-get install" \
  apt-get install -y -qq -o DPkg::Lock::Timeout=60 "${PACKAGES[@]}" || exit
have_all || { echo "system packages: ${PACKAGES[*]} installed, but initdb or chromium is still missing" >&2; exit 1; }
