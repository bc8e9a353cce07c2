#!/usr/bin/env python3
"""A third-party MAVLink peer for the twin's autopilot (`amstack twin serve --mavlink`).

pymavlink (not our code) plays a ground station or an offboard program and prints one JSON
object on stdout; tests/tests/mavlink.rs asserts on it. Run it with the venv of
scripts/setup-python.sh.

  rates     wait for the heartbeat, count every message for --seconds, request
            AUTOPILOT_VERSION and HOME_POSITION, arm, disarm (plain, then forced): the ACKs.
  robust    send random bytes, truncated frames, bad CRCs and unknown message ids, then arm
            and disarm: the ACKs and SYS_STATUS's error counters.
  signing   with --key-hex: a command unsigned, signed with a wrong key, signed with the key.
  serial    open a pseudo-terminal pair, print "pty PATH" on stderr (start the autopilot on
            serial:PATH:BAUD), then wait for its heartbeat on the other end, arm and force
            disarm: the ACKs and how many ODOMETRY arrived in --seconds.
  actuator  lockstep at actuator level: a few ticks while disarmed (must not step), offboard,
            arm, then --ticks ticks of group 2 (arm joint 0 at --joint-control, gripper open)
            and group 0 (every motor at --motor-u): the ODOMETRY times, thrusts and joints.
  failsafe  stream SET_ATTITUDE_TARGET (lockstep, a z PD loop on ODOMETRY), offboard, arm,
            hover --hover-s, stop; record the hold, the landing and the disarm.
"""

import argparse
import json
import math
import os
import random
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink2  # noqa: E402

def result_name(code):
    entry = mavlink2.enums["MAV_RESULT"].get(code)
    return entry.name.replace("MAV_RESULT_", "") if entry else str(code)


def connect(args, signing_key=None):
    m = mavutil.mavlink_connection(args.connect, source_system=255, source_component=190,
                                   dialect="common")
    if signing_key is not None:
        m.setup_signing(signing_key, sign_outgoing=True)
    return m


def heartbeat(m):
    m.mav.heartbeat_send(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)


def wait_heartbeat(m, timeout=15.0):
    end = time.time() + timeout
    last_sent = 0.0
    while time.time() < end:
        if time.time() - last_sent > 0.5:
            heartbeat(m)
            last_sent = time.time()
        msg = m.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
        if msg is not None and msg.get_srcSystem() == 1 and msg.get_srcComponent() == 1:
            return msg
    return None


def command(m, cmd, p1=0.0, p2=0.0, p3=0.0, p4=0.0, p5=0.0, p6=0.0, p7=0.0, timeout=3.0):
    """Sends a COMMAND_LONG; returns (result name or None, the STATUSTEXTs seen meanwhile)."""
    m.mav.command_long_send(1, 1, cmd, 0, p1, p2, p3, p4, p5, p6, p7)
    end = time.time() + timeout
    texts = []
    while time.time() < end:
        msg = m.recv_match(type=["COMMAND_ACK", "STATUSTEXT"], blocking=True, timeout=0.1)
        if msg is None:
            continue
        if msg.get_type() == "STATUSTEXT":
            texts.append(msg.text)
        elif msg.command == cmd:
            if msg.result != mavlink2.MAV_RESULT_ACCEPTED:
                # A refusal's STATUSTEXT follows its ACK.
                more = m.recv_match(type="STATUSTEXT", blocking=True, timeout=0.3)
                if more is not None:
                    texts.append(more.text)
            return result_name(msg.result), texts
    return None, texts


def cmd_rates(args):
    m = connect(args)
    hb = wait_heartbeat(m)
    if hb is None:
        return {"error": "no heartbeat"}
    counts = {}
    first_last = {}
    start = time.time()
    last_hb = 0.0
    while time.time() - start < args.seconds:
        if time.time() - last_hb > 1.0:
            heartbeat(m)
            last_hb = time.time()
        msg = m.recv_match(blocking=True, timeout=0.05)
        if msg is None or msg.get_srcSystem() != 1:
            continue
        now = time.time()
        counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
        first_last.setdefault(msg.get_type(), [now, now])[1] = now
    elapsed = time.time() - start
    out = {
        "heartbeat": {"type": hb.type, "autopilot": hb.autopilot, "base_mode": hb.base_mode,
                      "custom_mode": hb.custom_mode, "system_status": hb.system_status,
                      "mavlink_version": hb.get_msgbuf()[0] == 0xFD},
        "seconds": elapsed,
        "counts": counts,
        # (n − 1) intervals between the first and the last arrival.
        "rates_hz": {k: (n - 1) / (first_last[k][1] - first_last[k][0])
                     for k, n in sorted(counts.items()) if n > 1},
    }
    res, _ = command(m, mavlink2.MAV_CMD_REQUEST_MESSAGE, 148)
    version = m.recv_match(type="AUTOPILOT_VERSION", blocking=True, timeout=2)
    out["request_autopilot_version"] = res
    out["autopilot_version_received"] = version is not None
    out["capabilities"] = None if version is None else version.capabilities
    res, _ = command(m, mavlink2.MAV_CMD_REQUEST_MESSAGE, 242)
    home = m.recv_match(type="HOME_POSITION", blocking=True, timeout=2)
    out["request_home_position"] = res
    out["home"] = None if home is None else {"lat": home.latitude, "lon": home.longitude,
                                             "alt_mm": home.altitude}
    out["arm"], _ = command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    armed = m.recv_match(type="HEARTBEAT", blocking=True, timeout=2)
    out["armed_flag_after_arm"] = bool(armed and armed.base_mode & 128)
    time.sleep(0.5)
    out["disarm"], out["disarm_texts"] = command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    out["force_disarm"], _ = command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    out["unsupported_command"], _ = command(m, mavlink2.MAV_CMD_DO_SET_SERVO, 1, 1500)
    return out


def garbage(m, seed):
    """Random bytes, truncated frames, bad CRCs, unknown ids: (what was sent, counts)."""
    rng = random.Random(seed)
    sock_send = m.write
    good = m.mav.command_long_encode(1, 1, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0,
                                     148, 0, 0, 0, 0, 0, 0).pack(m.mav)
    sent = {"random": 0, "truncated": 0, "bad_crc": 0, "unknown_id": 0}
    for _ in range(args_garbage_rounds):
        sock_send(bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 300))))
        sent["random"] += 1
        sock_send(good[:rng.randint(1, len(good) - 1)])
        sent["truncated"] += 1
        bad = bytearray(good)
        bad[-1] ^= 0xA5
        sock_send(bytes(bad))
        sent["bad_crc"] += 1
        unknown = bytearray(good)
        unknown[7:10] = (0xEE, 0xEE, 0x0E)  # message id 0x0EEEEE: not in common
        sock_send(bytes(unknown))
        sent["unknown_id"] += 1
    return sent


args_garbage_rounds = 50


def cmd_robust(args):
    global args_garbage_rounds
    args_garbage_rounds = args.rounds
    m = connect(args)
    if wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    sent = garbage(m, args.seed)
    time.sleep(0.3)
    out = {"sent": sent}
    out["arm"], _ = command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out["force_disarm"], _ = command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    status = None
    end = time.time() + 3
    while time.time() < end:
        heartbeat(m)
        status = m.recv_match(type="SYS_STATUS", blocking=True, timeout=1.1)
        if status is not None and status.errors_comm > 0:
            break
    out["sys_status"] = None if status is None else {
        "errors_comm": status.errors_comm, "drop_rate_comm": status.drop_rate_comm,
        "errors_count1": status.errors_count1, "errors_count2": status.errors_count2,
        "errors_count3": status.errors_count3, "errors_count4": status.errors_count4}
    return out


def cmd_signing(args):
    key = bytes.fromhex(args.key_hex)
    out = {}
    # Unsigned.
    m = connect(args)
    heartbeat(m)
    out["unsigned"], _ = command(m, mavlink2.MAV_CMD_REQUEST_MESSAGE, 148, timeout=1.5)
    # Telemetry goes only to senders of accepted frames.
    out["unsigned_heard_heartbeat"] = m.recv_match(type="HEARTBEAT", blocking=True,
                                                   timeout=1.5) is not None
    m.close()
    # Signed with a wrong key.
    m = connect(args, signing_key=bytes(b ^ 0xFF for b in key))
    heartbeat(m)
    out["forged"], _ = command(m, mavlink2.MAV_CMD_REQUEST_MESSAGE, 148, timeout=1.5)
    m.close()
    # Signed with the key.
    m = connect(args, signing_key=key)
    heartbeat(m)
    out["signed"], _ = command(m, mavlink2.MAV_CMD_REQUEST_MESSAGE, 148, timeout=3)
    hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=2)
    out["heartbeat_signed"] = bool(hb is not None and hb.get_signed())
    return out


def cmd_serial(args):
    import select
    import tty
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    print("pty " + os.ttyname(slave), file=sys.stderr, flush=True)
    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    mav.robust_parsing = True

    def send(msg):
        os.write(master, msg.pack(mav))

    def receive(timeout):
        r, _, _ = select.select([master], [], [], timeout)
        if not r:
            return []
        try:
            data = os.read(master, 4096)
        except OSError:
            return []
        return mav.parse_buffer(data) or []

    def ack(cmd, *params, timeout=5.0):
        p = list(params) + [0.0] * (7 - len(params))
        send(mav.command_long_encode(1, 1, cmd, 0, *p))
        end = time.time() + timeout
        while time.time() < end:
            for msg in receive(0.1):
                if msg.get_type() == "COMMAND_ACK" and msg.command == cmd:
                    return result_name(msg.result)
        return None

    out = {"heartbeat": None}
    end = time.time() + args.watch_s
    while time.time() < end and out["heartbeat"] is None:
        send(mav.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0))
        for msg in receive(0.2):
            if msg.get_type() == "HEARTBEAT":
                out["heartbeat"] = {"type": msg.type, "autopilot": msg.autopilot}
    if out["heartbeat"] is None:
        return out
    counts = {}
    start = time.time()
    while time.time() - start < args.seconds:
        for msg in receive(0.1):
            counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
    out["counts"] = counts
    out["arm"] = ack(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out["force_disarm"] = ack(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    return out


def cmd_actuator(args):
    m = connect(args)
    if wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    out = {}
    motors = [args.motor_u] * args.rotors + [0.0] * (8 - args.rotors)
    arm = [args.joint_control] + [0.0] * 7
    arm[args.arm_joints] = 1.0  # the gripper, after the arm joints: open

    def tick():
        m.mav.set_actuator_control_target_send(0, 2, 1, 1, arm)
        m.mav.set_actuator_control_target_send(0, 0, 1, 1, motors)

    first = m.recv_match(type="ODOMETRY", blocking=True, timeout=2)
    for _ in range(5):
        tick()
        time.sleep(0.05)
    idle = m.recv_match(type="ODOMETRY", blocking=True, timeout=2)
    out["disarmed_time_usec"] = [first.time_usec, idle.time_usec]
    out["offboard"], _ = command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 6, 0)
    out["arm"], _ = command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    times = []
    last = {"t": 0}
    thrusts = None
    joints = None
    z = []
    for _ in range(args.ticks):
        tick()
        end = time.time() + 2
        while time.time() < end:
            msg = m.recv_match(type=["ODOMETRY", "ACTUATOR_OUTPUT_STATUS", "DEBUG_FLOAT_ARRAY"],
                               blocking=True, timeout=0.2)
            if msg is None:
                continue
            if msg.get_type() == "ACTUATOR_OUTPUT_STATUS":
                thrusts = list(msg.actuator[:msg.active])
            elif msg.get_type() == "DEBUG_FLOAT_ARRAY":
                joints = list(msg.data[:16])
            elif msg.time_usec > last["t"]:
                last["t"] = msg.time_usec
                times.append(msg.time_usec)
                z.append(-msg.z)
                break
    out["times_usec"] = times
    out["thrusts_n"] = thrusts
    out["joints"] = joints
    out["z_m"] = [min(z), max(z)] if z else None
    out["force_disarm"], _ = command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    return out


def quat_mul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def tilt_deg(q):
    # Angle between body z (FRD down) and NED down.
    w, x, y, z = q
    zz = 1 - 2 * (x * x + y * y)
    return math.degrees(math.acos(max(-1.0, min(1.0, zz))))


def cmd_failsafe(args):
    m = connect(args)
    if wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    out = {}
    # HEARTBEAT at 20 Hz instead of 1 Hz: the offboard timeout (COM_OF_LOSS_T, 0.5 s) is shorter
    # than the default heartbeat period, so at 1 Hz the OFFBOARD sample after the stream stops
    # would be seen in only about half of the runs.
    out["heartbeat_interval"], _ = command(m, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 50_000)
    # Level, facing east (amstack's reset: yaw 0 = east = PX4 yaw 90°).
    q = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))
    hover = args.hover_thrust

    last = {"odo": None}

    def setpoint(thrust_z):
        # pymavlink's common dialect has no thrust_body: the collective thrust (body up).
        m.mav.set_attitude_target_send(0, 1, 1, 0, q, 0, 0, 0, thrust_z)

    def pd_thrust(odo, z_target_ned):
        ez = odo.z - z_target_ned  # > 0: too low (NED z down)
        return hover * (1 + (4.0 * ez + 3.0 * odo.vz) / 9.81)

    def wait_odometry(after_us, timeout=2.0):
        end = time.time() + timeout
        while time.time() < end:
            msg = m.recv_match(type="ODOMETRY", blocking=True, timeout=0.2)
            if msg is not None and msg.time_usec > after_us:
                last["odo"] = msg
                return msg
        return None

    out["offboard_without_setpoints"], _ = command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 6, 0)
    odo = m.recv_match(type="ODOMETRY", blocking=True, timeout=2)
    z0 = odo.z
    for _ in range(5):
        setpoint(hover)
        time.sleep(0.05)
    out["offboard_with_setpoints"], _ = command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 6, 0)
    time.sleep(0.8)  # the stream stops: arming in offboard must be refused
    out["arm_without_setpoints"], out["arm_refusal_texts"] = command(
        m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    for _ in range(5):
        setpoint(hover)
        time.sleep(0.05)
    out["arm"], _ = command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    # Lockstep hover: one setpoint per tick, each answered by its ODOMETRY.
    t_us = 0
    ticks = int(args.hover_s * args.rate_hz)
    max_tilt = 0.0
    for k in range(ticks):
        cur = last["odo"] or odo
        # Climbing at --climb-mps: the setpoints stop while the vehicle moves.
        setpoint(pd_thrust(cur, z0 - args.climb_mps * k / args.rate_hz))
        got = wait_odometry(t_us)
        if got is None:
            out["error"] = "lockstep: no ODOMETRY for a setpoint at t = %d us" % t_us
            return out
        t_us = got.time_usec
        max_tilt = max(max_tilt, tilt_deg(got.q))
    stop = last["odo"]
    out["stopped_at"] = {"t_s": stop.time_usec / 1e6, "x": stop.x, "y": stop.y, "z": stop.z,
                         "vz": stop.vz}
    # Setpoints stop: watch the failsafe.
    modes = []
    hold_dev = 0.0
    z_min = stop.z
    disarmed_at = None
    end = time.time() + args.watch_s
    last_hb = 0.0
    final = stop
    while time.time() < end:
        if time.time() - last_hb > 1.0:
            heartbeat(m)
            last_hb = time.time()
        msg = m.recv_match(type=["ODOMETRY", "HEARTBEAT"], blocking=True, timeout=0.2)
        if msg is None:
            continue
        if msg.get_type() == "HEARTBEAT":
            if msg.get_srcSystem() != 1:
                continue
            armed = bool(msg.base_mode & 128)
            main, sub = (msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF
            entry = {"main": main, "sub": sub, "armed": armed, "status": msg.system_status}
            if not modes or modes[-1] != entry:
                modes.append(entry)
            if not armed and disarmed_at is None:
                disarmed_at = final.time_usec / 1e6
                end = min(end, time.time() + 1.0)
            continue
        final = msg
        max_tilt = max(max_tilt, tilt_deg(msg.q))
        z_min = max(z_min, msg.z)  # NED: larger z is lower
        in_hold = modes and modes[-1]["main"] == 4 and modes[-1]["sub"] == 3
        if in_hold:
            hold_dev = max(hold_dev, math.dist((msg.x, msg.y, msg.z), (stop.x, stop.y, stop.z)))
    out["modes"] = modes
    out["hold_max_deviation_m"] = hold_dev
    out["max_tilt_deg"] = max_tilt
    out["final"] = {"t_s": final.time_usec / 1e6, "z_ned": final.z, "speed": math.sqrt(
        final.vx ** 2 + final.vy ** 2 + final.vz ** 2)}
    out["disarmed_at_s"] = disarmed_at
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("mode", choices=["rates", "robust", "signing", "serial", "actuator",
                                    "failsafe"])
    p.add_argument("--rotors", type=int, default=6)
    p.add_argument("--arm-joints", type=int, default=4)
    p.add_argument("--motor-u", type=float, default=0.5)
    p.add_argument("--joint-control", type=float, default=0.5)
    p.add_argument("--ticks", type=int, default=60)
    p.add_argument("--connect", default="", help="pymavlink address, e.g. udpout:127.0.0.1:14540")
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--rounds", type=int, default=50)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--key-hex", default="")
    p.add_argument("--hover-thrust", type=float, default=0.3)
    p.add_argument("--hover-s", type=float, default=1.0)
    p.add_argument("--rate-hz", type=float, default=120.0)
    p.add_argument("--watch-s", type=float, default=20.0)
    p.add_argument("--climb-mps", type=float, default=0.0)
    args = p.parse_args()
    run = {"rates": cmd_rates, "robust": cmd_robust, "signing": cmd_signing,
           "serial": cmd_serial, "actuator": cmd_actuator, "failsafe": cmd_failsafe}[args.mode]
    print(json.dumps(run(args)))


if __name__ == "__main__":
    sys.exit(main())
