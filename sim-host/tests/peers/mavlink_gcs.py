"""A ground control station made of pymavlink, as the station's MAVLink test peer (sim-host/tests/mavlink_gcs.rs).

Listens on udpin:127.0.0.1:0 (the port printed as `port N`), waits for the vehicle's heartbeat, reads the
parameter list, sets one parameter and reads it back, arms, takes off, waits for the hover, lands and waits
for the disarmed heartbeat, recording every ATTITUDE, LOCAL_POSITION_NED, STATUSTEXT and COMMAND_ACK. Writes
what it saw as JSON to argv[1]. Exit 0 when the script ran to its end, 1 (with the reason on stderr) if not.
"""
import json
import sys
import time

from pymavlink import mavutil

OUT = sys.argv[1]
SET_NAME = sys.argv[2] if len(sys.argv) > 2 else "TrajectorySpeed"

conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255, source_component=190)
print("port", conn.port.getsockname()[1], flush=True)
t0 = time.monotonic()
seen = {
    "attitude": [],
    "local_position_ned": [],
    "attitude_quaternion": 0,
    "statustext": [],
    "acks": [],
    "heartbeats": 0,
    "sys_status": 0,
    "params": {},
    "param_count": None,
    "modes": [],
}
last_hb = None


def record(m):
    global last_hb
    t = m.get_type()
    if t == "ATTITUDE":
        seen["attitude"].append([m.time_boot_ms, m.roll, m.pitch, m.yaw])
    elif t == "LOCAL_POSITION_NED":
        seen["local_position_ned"].append([m.time_boot_ms, m.x, m.y, m.z, m.vx, m.vy, m.vz])
    elif t == "ATTITUDE_QUATERNION":
        seen["attitude_quaternion"] += 1
    elif t == "STATUSTEXT":
        seen["statustext"].append(m.text)
    elif t == "COMMAND_ACK":
        seen["acks"].append([m.command, m.result])
    elif t == "SYS_STATUS":
        seen["sys_status"] += 1
    elif t == "PARAM_VALUE":
        seen["params"][m.param_id] = [m.param_index, m.param_value]
        seen["param_count"] = m.param_count
    elif t == "HEARTBEAT":
        seen["heartbeats"] += 1
        last_hb = m
        armed = bool(m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        state = [m.custom_mode, armed, m.system_status]
        if not seen["modes"] or seen["modes"][-1] != state:
            seen["modes"].append(state)


def pump(until, timeout, what):
    """Reads and records messages until `until(message)` holds; fails naming `what` after `timeout` s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        m = conn.recv_match(blocking=True, timeout=0.1)
        if m is None:
            continue
        record(m)
        if until(m):
            return m
    finish(f"timed out after {timeout} s waiting for {what}")


def finish(error=None):
    seen["error"] = error
    seen["seconds"] = time.monotonic() - t0
    with open(OUT, "w") as f:
        json.dump(seen, f)
    if error:
        print(error, file=sys.stderr, flush=True)
        sys.exit(1)
    sys.exit(0)


def is_type(t):
    return lambda m: m.get_type() == t


def heartbeat_where(pred):
    return lambda m: m.get_type() == "HEARTBEAT" and pred(m)


def command(cmd, p1=0.0, p2=0.0, tries=20, retry_s=0.5):
    """COMMAND_LONG until accepted (a temporary rejection is retried): the results seen."""
    results = []
    for _ in range(tries):
        conn.mav.command_long_send(1, 1, cmd, 0, p1, p2, 0, 0, 0, 0, 0)
        ack = pump(lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd, 5.0, f"COMMAND_ACK of {cmd}")
        results.append(ack.result)
        if ack.result == mavutil.mavlink.MAV_RESULT_ACCEPTED:
            return results
        time.sleep(retry_s)
    finish(f"command {cmd} not accepted: {results}")


hb = pump(is_type("HEARTBEAT"), 30.0, "the first heartbeat")
seen["first_heartbeat_s"] = time.monotonic() - t0
seen["vehicle"] = [hb.get_srcSystem(), hb.get_srcComponent(), hb.type, hb.autopilot]
# The vehicle's telemetry has arrived (standby, disarmed) before anything is asked.
pump(heartbeat_where(lambda m: m.system_status == mavutil.mavlink.MAV_STATE_STANDBY), 30.0, "a standby heartbeat")

# The parameter list, in full.
conn.mav.param_request_list_send(1, 1)
pump(
    lambda m: seen["param_count"] is not None and len(seen["params"]) >= seen["param_count"],
    15.0,
    "the whole parameter list",
)
seen["params_listed"] = dict(seen["params"])
before = seen["params"][SET_NAME][1]
wanted = round(before * 0.75, 3)
conn.mav.param_set_send(1, 1, SET_NAME.encode(), wanted, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
echo = pump(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == SET_NAME, 5.0, "the PARAM_SET echo")
conn.mav.param_request_read_send(1, 1, SET_NAME.encode(), -1)
read = pump(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == SET_NAME, 5.0, "the PARAM_REQUEST_READ answer")
seen["param_set"] = {"name": SET_NAME, "before": before, "wanted": wanted, "echo": echo.param_value, "read": read.param_value}

seen["arm_results"] = command(mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
pump(heartbeat_where(lambda m: m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED), 5.0, "an armed heartbeat")
seen["takeoff_results"] = command(mavutil.mavlink.MAV_CMD_NAV_TAKEOFF)
pump(heartbeat_where(lambda m: m.custom_mode == 3), 30.0, "the hover (custom mode 3)")
hover_until = time.monotonic() + 2.0
pump(lambda m: time.monotonic() > hover_until, 10.0, "two seconds of hover")
seen["land_results"] = command(mavutil.mavlink.MAV_CMD_NAV_LAND)
pump(
    heartbeat_where(lambda m: not (m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)),
    60.0,
    "the disarmed heartbeat after the landing",
)
finish()
