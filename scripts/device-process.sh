# device-process.sh - a device of your own's process group, for scripts/bench-run (sourced): start
# DEVICE_CMD, stop it, and the fault steps the orchestrator asks for (canbench.device_control), on
# that group or, for a device the bench does not start, through the user's DEVICE_HOOK.
# Uses bench-run's variables: DEVICE_CMD, DEVICE_HOOK, DEVICE_STOP_S, DEVICE_HOOK_TIMEOUT_S,
# identities, device_endpoint, canbus_dir, repo, caller_dir, run_dir; sets device_pid, device_group,
# hook_stopped (and device_paths: device_config, device_settings, device_preload); requests and
# replies, once set, are the orchestrator's FIFOs' descriptors (never the device's nor the hook's).

stop_device() {  # its whole process group, its leader gone or not: TERM, then KILL after DEVICE_STOP_S
	[ -n "$device_group" ] || return 0
	if kill -TERM -- -"$device_group" 2>/dev/null; then
		group_gone "${DEVICE_STOP_S:-10}"
		kill -KILL -- -"$device_group" 2>/dev/null || true
	fi
	device_group=''
}
group_gone() {  # until the device's process group is empty, at most $1 s
	local deadline=$((SECONDS + $1))
	while kill -0 -- -"$device_group" 2>/dev/null && [ $SECONDS -lt $deadline ]; do sleep 0.05; done
}
device_paths() {  # the device's identity (its Zenoh config), the scenario's settings, the preload library
	device_config=${identities:-}/device/zenoh.json5 device_settings=${identities:-}/device.env
	device_preload=${repo:-}/build/ucan/libucan-preload.so
}
launch_device() {  # DEVICE_CMD in a process group of its own, its output added to device.log
	(
		device_paths
		# the scenario's settings only: none the caller's shell holds (a ZENOH_LISTEN would open a listener)
		unset LD_PRELOAD $(compgen -e | grep -E '^(ZENOH_|UCAN_)' || true)
		set -a
		. "$device_settings"
		ZENOH_CONFIG=$device_config ZENOH_ROUTER_ADDRESS=$device_endpoint UCAN_DIR=$canbus_dir LD_PRELOAD=$device_preload
		set +a
		cd "$caller_dir"  # DEVICE_CMD's relative paths are the caller's
		# the orchestrator's channel to bench-run is not the device's
		[ -z "${requests:-}" ] || exec {requests}<&- {replies}<&-
		exec setsid bash -c "$DEVICE_CMD"
	) >>"$run_dir/device.log" 2>&1 </dev/null &
	device_pid=$! device_group=$!  # setsid: the device leads its own group (never a leader here, so no fork)
	# a signal to its group finds it only once setsid ran (microseconds; bounded all the same)
	local deadline=$((SECONDS + 5))
	until device_grouped || [ $SECONDS -ge $deadline ]; do sleep 0.01; done
}
device_grouped() {  # the device leads its own process group by now, or it is gone already
	local stat
	stat=$(cat "/proc/$device_pid/stat" 2>/dev/null) || return 0
	set -- ${stat##*) }  # after the command's name: state, parent, process group
	[ "$3" = "$device_pid" ]
}
# A fault step on the device, asked by the orchestrator (canbench.device_control): "SEQ ACTION HOLD_S"
# in, "SEQ ok STOPPED_NS STARTED_NS" or "SEQ error WHY" out. Served from the watch loop below, one
# at a time; never on a device that already exited (its exit is the run's verdict, not a restart).
device_fault() {
	local action=$2 hold=$3 stopped started
	case $hold in '' | *[!0-9.]* | *.*.*) echo "$1 error hold '$hold': not a number of seconds"; return ;; esac
	case $action in bridge_term | bridge_kill) ;; *) echo "$1 error $action is not a fault step on the device"; return ;; esac
	if [ -n "${DEVICE_HOOK:-}" ]; then
		hook_fault "$@"
		return
	fi
	if ! kill -0 "$device_pid" 2>/dev/null; then
		echo "$1 error the device had exited before $action"
		return
	fi
	stopped=${EPOCHREALTIME//[!0-9]/}000  # the wall clock in ns as the captures stamp (bash's: no fork)
	if [ "$action" = bridge_term ]; then
		stop_device  # TERM, then KILL after DEVICE_STOP_S, as at the run's end
	else
		{
			kill -KILL -- -"$device_group" || true
			group_gone 10  # once the kernel has reaped every member (KILL cannot be ignored)
		} 2>/dev/null  # (and bash's word that its job was killed)
		device_group=''
	fi
	{ wait "$device_pid" || true; } 2>/dev/null
	echo "bench-run: device: $action, started again after ${hold}s" >>"$run_dir/device.log"
	sleep "$hold"  # the fault's length, as the scenario says
	# taken before the start: the new incarnation's first frame may come within milliseconds, and
	# the checks count its frames (its counters) from the window's end on
	started=${EPOCHREALTIME//[!0-9]/}000
	launch_device
	echo "bench-run: device: $action at $(date -u -d "@${stopped%?????????}" +%T), started again (pid $device_pid)" >&2
	echo "$1 ok $stopped $started"
}

# The same step on a device the bench did not start (a board, a program started by hand): the user's
# DEVICE_HOOK does it, run as `DEVICE_HOOK stop ACTION`, then after the hold `DEVICE_HOOK start
# ACTION`. The window: from just before the stop to just before the start (the device's own boot and
# reconnection after it are inside the fault's settling, as a restarted bridge's are).
hook_fault() {
	local action=$2 hold=$3 stopped started rc=0
	stopped=${EPOCHREALTIME//[!0-9]/}000
	hook_stopped=$action  # from here on the run's end gives the device back (bench-run's cleanup)
	run_hook stop "$action" || rc=$?
	if [ $rc -ne 0 ]; then
		echo "$1 error DEVICE_HOOK stop $action $(hook_failed $rc)"
		return
	fi
	sleep "$hold"
	started=${EPOCHREALTIME//[!0-9]/}000
	# cleared first: an interrupt lets the call finish, and the run's end must not call it again
	hook_stopped=''
	run_hook start "$action" || rc=$?
	if [ $rc -ne 0 ]; then
		echo "$1 error DEVICE_HOOK start $action $(hook_failed $rc)"
		return
	fi
	echo "bench-run: device: $action through DEVICE_HOOK at $(date -u -d "@${stopped%?????????}" +%T), started again after ${hold}s" >&2
	echo "$1 ok $stopped $started"
}
run_hook() {  # DEVICE_HOOK with its two words, in the caller's directory, its output added to device.log, bounded
	echo "bench-run: device: DEVICE_HOOK $*" >>"$run_dir/device.log"
	hook_began=$SECONDS
	(
		cd "$caller_dir"  # the hook's relative paths are the caller's
		[ -z "${requests:-}" ] || exec {requests}<&- {replies}<&-
		# what a hook restarting a program on this machine needs (the run's identity, router, bus)
		device_paths
		export DEVICE_HOOK_ACTION=$1 DEVICE_HOOK_STEP=$2 DEVICE_ZENOH_CONFIG=$device_config \
			DEVICE_ENV_FILE=$device_settings DEVICE_ROUTER_ADDRESS=${device_endpoint:-} DEVICE_UCAN_DIR=${canbus_dir:-} \
			DEVICE_PRELOAD=$device_preload
		exec timeout -k 5 "${DEVICE_HOOK_TIMEOUT_S:-20}" bash -c "$DEVICE_HOOK"' "$@"' device-hook "$@"
	) >>"$run_dir/device.log" 2>&1 </dev/null
}
hook_failed() {  # why a hook's call failed, from its exit status and how long it ran
	if { [ "$1" -eq 124 ] || [ "$1" -eq 137 ]; } && [ $((SECONDS - hook_began)) -ge "${DEVICE_HOOK_TIMEOUT_S:-20}" ]; then
		echo "did not finish within DEVICE_HOOK_TIMEOUT_S=${DEVICE_HOOK_TIMEOUT_S:-20} s (see device.log)"
	else
		echo "exited with $1 (see device.log)"
	fi
}
