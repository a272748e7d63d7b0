#!/usr/bin/env bash
# Installs what the viewer's browser tests need (crates/viewer/tests/browser.rs):
# Chromium from Debian (headless, software WebGL) and playwright-core from the
# committed package-lock.json in crates/viewer/e2e. Idempotent: does nothing
# when both are present. Needs root (or sudo) for apt-get when Chromium is
# missing. Usage: scripts/setup-browser.sh
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
e2e="$root/crates/viewer/e2e"

missing=()
[ -x /usr/bin/chromium ] || missing+=(chromium)
command -v node >/dev/null 2>&1 || missing+=(nodejs)
command -v npm >/dev/null 2>&1 || missing+=(npm)
if [ ${#missing[@]} -gt 0 ]; then
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# npm ci only when the installed tree does not match the lock file.
stamp="$e2e/node_modules/.colslam-lock-stamp"
if [ -f "$e2e/node_modules/playwright-core/package.json" ] && [ -f "$stamp" ] && cmp -s "$e2e/package-lock.json" "$stamp"; then
  echo "browser test dependencies up to date"
else
  (cd "$e2e" && npm ci --no-audit --no-fund)
  cp "$e2e/package-lock.json" "$stamp"
fi
/usr/bin/chromium --version 2>/dev/null || true
node --version
