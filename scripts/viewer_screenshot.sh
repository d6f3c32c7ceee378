#!/usr/bin/env bash
# Open a dataset in the Rerun viewer on a virtual display and save a screenshot of the whole screen: the check
# a person makes by looking. Needs the Debian packages xvfb and imagemagick.
#   bash scripts/viewer_screenshot.sh DIR EPISODE OUT.png [SECONDS_TO_WAIT]
#   bash scripts/viewer_screenshot.sh DIR run OUT.png [SECONDS_TO_WAIT]     # the run's own recordings
# The recording is the one `babblegen view DIR --episode EPISODE` shows (written with --save, then opened by a
# viewer this script starts), or with `run` the run's recording segments (DIR/babblegen/rerun/*.rrd); the script
# ends only the processes it started, by pid.
set -euo pipefail
dir=$1 episode=$2 shot=$3 wait=${4:-45}
cd "$(dirname "$0")/.."
display=:${BABBLEGEN_DISPLAY:-99}
recording=$(mktemp --suffix=.rrd)
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
  rm -f "$recording"
}
trap cleanup EXIT
Xvfb "$display" -screen 0 1600x900x24 >/dev/null 2>&1 &
pids+=($!)
if [ "$episode" = run ]; then
  recordings=("$dir"/babblegen/rerun/segment-*.rrd)
else
  .venv/bin/babblegen view "$dir" --episode "$episode" --save "$recording" >/dev/null
  recordings=("$recording")
fi
# the viewer binary itself (the `rerun` console script runs it as a child, which killing the script would leave)
viewer=$(.venv/bin/python -c 'import os, rerun_cli; print(os.path.join(os.path.dirname(rerun_cli.__file__), "rerun"))')
DISPLAY=$display "$viewer" "${recordings[@]}" >/dev/null 2>&1 &
pids+=($!)
sleep "$wait"
DISPLAY=$display import -window root "$shot"
echo "screenshot: $shot"
