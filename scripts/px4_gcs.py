#!/usr/bin/env python3
"""pymavlink (not our code) against the twin's autopilot as a PX4 client would use it: the
parameter and mission protocols, COMMAND_INT, takeoff / reposition / hold / RTL / land,
position and attitude offboard, body-rate limits, MAVLink 1 peers and fuzzing. One JSON object
on stdout; tests/tests/px4.rs asserts on it. Run it with the venv of scripts/setup-python.sh.

  params    list, read (by name, by index, unknown), set (typed, range-checked, INT32
            bytewise), then the behaviour: MIS_TAKEOFF_ALT sets the takeoff altitude,
            COM_OF_LOSS_T how old a setpoint may be for OFFBOARD.
  mission   upload takeoff + 3 waypoints + land (MISSION_INT), download it back, fly it in
            AUTO.MISSION: MISSION_ITEM_REACHED, MISSION_CURRENT, landed, disarmed.
  auto      arm, NAV_TAKEOFF, DO_REPOSITION (COMMAND_INT), hold, RTL (disarms at home), arm,
            NAV_LAND (disarms).
  position  lockstep SET_POSITION_TARGET_LOCAL_NED to --target N E D: the final position.
  attitude  lockstep SET_ATTITUDE_TARGET with thrust_body (raw frame: pymavlink's common
            dialect has no thrust_body) level with a forward body force: the motion.
  rates     lockstep body-rate setpoints (attitude ignored) of 50 rad/s, 1e30 rad/s and NaN:
            the largest roll rate seen.
  actuator  SET_ACTUATOR_CONTROL_TARGET without --allow-actuator-setpoints: motors refused
            with a STATUSTEXT, OFFBOARD refused (no setpoint stream), the arm group accepted.
  v1        a MAVLink 1 ground station (pymavlink's default): heartbeat and an ACK in v1.
  fuzz      --frames random, garbled, truncated, MAVLink 1, unknown-id frames and valid
            frames of every setpoint and protocol message with non-finite and huge values;
            then the vehicle's state, the parameters and a command's ACK.
"""

import argparse
import json
import math
import os
import random
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import mavlink_gcs as g  # noqa: E402  (sets MAVLINK20=1 before pymavlink loads)
from pymavlink.dialects.v20 import common as mavlink2  # noqa: E402
from pymavlink.generator.mavcrc import x25crc  # noqa: E402

NAN = float("nan")
INF = float("inf")
HOME_LAT, HOME_LON, HOME_ALT = 47.397742, 8.545594, 488.0
EARTH_R = 6371000.0


def latlon(north, east):
    lat = HOME_LAT + math.degrees(north / EARTH_R)
    lon = HOME_LON + math.degrees(east / (EARTH_R * math.cos(math.radians(HOME_LAT))))
    return int(round(lat * 1e7)), int(round(lon * 1e7))


def mode_of(hb):
    return (hb.custom_mode >> 16) & 0xFF, (hb.custom_mode >> 24) & 0xFF


def param_bytes_int(v):
    return struct.unpack("<f", struct.pack("<i", v))[0]


def param_int_value(f):
    return struct.unpack("<i", struct.pack("<f", f))[0]


def send_pump(m):
    """Keeps the ground-station heartbeat going (the twin answers peers it heard)."""
    now = time.time()
    if now - send_pump.last > 1.0:
        g.heartbeat(m)
        send_pump.last = now


send_pump.last = 0.0


def param_set(m, name, value, ptype=mavlink2.MAV_PARAM_TYPE_REAL32, timeout=2.0):
    m.mav.param_set_send(1, 1, name.encode(), value, ptype)
    end = time.time() + timeout
    texts = []
    while time.time() < end:
        msg = m.recv_match(type=["PARAM_VALUE", "STATUSTEXT"], blocking=True, timeout=0.1)
        if msg is None:
            continue
        if msg.get_type() == "STATUSTEXT":
            texts.append(msg.text)
        elif msg.param_id == name:
            more = m.recv_match(type="STATUSTEXT", blocking=True, timeout=0.2)
            if more is not None:
                texts.append(more.text)
            return msg, texts
    return None, texts


def wait_mode(m, main, sub=None, armed=None, timeout=30.0, watch=None):
    """Waits for a HEARTBEAT in (main, sub) (and armed state); `watch(msg)` sees the rest."""
    end = time.time() + timeout
    while time.time() < end:
        send_pump(m)
        msg = m.recv_match(blocking=True, timeout=0.1)
        if msg is None:
            continue
        if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == 1:
            ma, su = mode_of(msg)
            is_armed = bool(msg.base_mode & 128)
            if ma == main and (sub is None or su == sub) and (armed is None or armed == is_armed):
                return msg
        elif watch is not None:
            watch(msg)
    return None


def wait_disarmed(m, timeout=60.0, watch=None):
    end = time.time() + timeout
    while time.time() < end:
        send_pump(m)
        msg = m.recv_match(blocking=True, timeout=0.1)
        if msg is None:
            continue
        if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == 1:
            if not msg.base_mode & 128:
                return msg
        elif watch is not None:
            watch(msg)
    return None


def local_position(m, timeout=2.0):
    return m.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=timeout)


def cmd_params(args):
    m = g.connect(args)
    if g.wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    out = {}
    m.mav.param_request_list_send(1, 1)
    values = {}
    count = None
    end = time.time() + 5
    while time.time() < end and (count is None or len(values) < count):
        msg = m.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
        if msg is None:
            continue
        count = msg.param_count
        v = msg.param_value
        if msg.param_type == mavlink2.MAV_PARAM_TYPE_INT32:
            v = param_int_value(v)
        values[msg.param_id] = {"value": v, "type": msg.param_type, "index": msg.param_index}
    out["count"] = count
    out["list"] = values
    m.mav.param_request_read_send(1, 1, b"MPC_XY_VEL_MAX", -1)
    msg = m.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
    out["read_by_name"] = None if msg is None else [msg.param_id, msg.param_value]
    m.mav.param_request_read_send(1, 1, b"", 0)
    msg = m.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
    out["read_by_index_0"] = None if msg is None else msg.param_id
    m.mav.param_request_read_send(1, 1, b"NO_SUCH_PARAM", -1)
    got = []
    end = time.time() + 1.0
    while time.time() < end:
        msg = m.recv_match(type=["PARAM_VALUE", "STATUSTEXT"], blocking=True, timeout=0.1)
        if msg is not None:
            got.append(msg.get_type() + ":" + (msg.text if msg.get_type() == "STATUSTEXT"
                                                else msg.param_id))
    out["read_unknown"] = got
    v, t = param_set(m, "MIS_TAKEOFF_ALT", args.takeoff_alt)
    out["set_takeoff_alt"] = [None if v is None else v.param_value, t]
    v, t = param_set(m, "MPC_XY_VEL_MAX", 1e9)
    out["set_out_of_range"] = [None if v is None else v.param_value, t]
    v, t = param_set(m, "MPC_XY_VEL_MAX", NAN)
    out["set_nan"] = [None if v is None else v.param_value, t]
    v, t = param_set(m, "COM_OBL_RC_ACT", param_bytes_int(4), mavlink2.MAV_PARAM_TYPE_INT32)
    out["set_int32"] = [None if v is None else param_int_value(v.param_value), t]
    v, t = param_set(m, "COM_OBL_RC_ACT", 4.0, mavlink2.MAV_PARAM_TYPE_REAL32)
    out["set_int32_as_real"] = [None if v is None else param_int_value(v.param_value), t]
    v, t = param_set(m, "NO_SUCH_PARAM", 1.0)
    out["set_unknown"] = [None if v is None else v.param_value, t]
    # Behaviour 1: COM_OF_LOSS_T is how old the last setpoint may be for OFFBOARD.
    q = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))
    for loss_t in (0.5, 30.0):
        param_set(m, "COM_OF_LOSS_T", loss_t)
        m.mav.set_attitude_target_send(0, 1, 1, 0, q, 0, 0, 0, 0.0)
        time.sleep(1.5)
        res, _ = g.command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 6, 0)
        out["offboard_1p5s_after_a_setpoint_with_loss_t_%g" % loss_t] = res
        g.command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 3, 0)
    # Behaviour 2: MIS_TAKEOFF_ALT is where NAV_TAKEOFF climbs.
    out["arm"], _ = g.command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out["takeoff"], _ = g.command(m, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN)
    hb = wait_mode(m, 4, 3, armed=True, timeout=30)
    out["loiter_after_takeoff"] = hb is not None
    time.sleep(1.0)
    lp = local_position(m)
    out["altitude_after_takeoff"] = None if lp is None else -lp.z
    g.command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    return out


def mission_item(seq, command, frame, x, y, z, p1=0.0, p2=0.0, p3=0.0, p4=NAN):
    return mavlink2.MAVLink_mission_item_int_message(1, 1, seq, frame, command, 0, 1, p1, p2, p3,
                                                     p4, x, y, z, 0)


def cmd_mission(args):
    m = g.connect(args)
    if g.wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    out = {}
    rel = mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    pts = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    items = [mission_item(0, mavlink2.MAV_CMD_NAV_TAKEOFF, rel, 0, 0, args.alt)]
    for i, (n, e) in enumerate(pts[1:]):
        lat, lon = latlon(n, e)
        items.append(mission_item(i + 1, mavlink2.MAV_CMD_NAV_WAYPOINT, rel, lat, lon, args.alt,
                                  p2=0.1))
    items.append(mission_item(4, mavlink2.MAV_CMD_NAV_LAND, rel, 0, 0, 0.0))
    out["mode_mission_without_mission"], _ = g.command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 4, 4)
    # Upload.
    m.mav.mission_count_send(1, 1, len(items), 0)
    requested = []
    ack = None
    end = time.time() + 10
    while time.time() < end:
        msg = m.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"],
                           blocking=True, timeout=0.2)
        if msg is None:
            continue
        if msg.get_type() == "MISSION_ACK":
            ack = msg.type
            break
        requested.append(msg.seq)
        m.mav.send(items[msg.seq])
    out["upload_requested"] = requested
    out["upload_ack"] = ack
    # Download.
    m.mav.mission_request_list_send(1, 1, 0)
    cnt = m.recv_match(type="MISSION_COUNT", blocking=True, timeout=2)
    out["download_count"] = None if cnt is None else cnt.count
    down = []
    for seq in range(cnt.count if cnt else 0):
        m.mav.mission_request_int_send(1, 1, seq, 0)
        it = m.recv_match(type="MISSION_ITEM_INT", blocking=True, timeout=2)
        if it is not None:
            down.append([it.seq, it.command, it.x, it.y, round(it.z, 3)])
    m.mav.mission_ack_send(1, 1, 0, 0)
    out["download"] = down
    out["uploaded"] = [[it.seq, it.command, it.x, it.y, round(it.z, 3)] for it in items]
    # Fly.
    out["mode_mission"], _ = g.command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 4, 4)
    out["arm"], _ = g.command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    reached = []
    currents = []
    positions = {}
    landed_states = []
    last_lp = {"lp": None}

    def watch(msg):
        t = msg.get_type()
        if t == "MISSION_ITEM_REACHED":
            reached.append(msg.seq)
            if last_lp["lp"] is not None:
                lp = last_lp["lp"]
                positions[msg.seq] = [lp.x, lp.y, lp.z]
        elif t == "MISSION_CURRENT":
            if not currents or currents[-1] != msg.seq:
                currents.append(msg.seq)
        elif t == "LOCAL_POSITION_NED":
            last_lp["lp"] = msg
        elif t == "EXTENDED_SYS_STATE":
            if not landed_states or landed_states[-1] != msg.landed_state:
                landed_states.append(msg.landed_state)

    hb = wait_disarmed(m, timeout=args.timeout, watch=watch)
    out["disarmed"] = hb is not None
    out["reached"] = reached
    out["reached_at_ned"] = positions
    out["current_seq"] = currents
    out["landed_states"] = landed_states
    lp = local_position(m)
    out["final_ned"] = None if lp is None else [lp.x, lp.y, lp.z]
    # Clear.
    m.mav.mission_clear_all_send(1, 1, 0)
    a = m.recv_match(type="MISSION_ACK", blocking=True, timeout=2)
    out["clear_ack"] = None if a is None else a.type
    m.mav.mission_request_list_send(1, 1, 0)
    cnt = m.recv_match(type="MISSION_COUNT", blocking=True, timeout=2)
    out["count_after_clear"] = None if cnt is None else cnt.count
    return out


def command_int(m, cmd, frame=mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, p1=0.0, p2=0.0, p3=0.0,
                p4=0.0, x=0, y=0, z=0.0, timeout=3.0):
    m.mav.command_int_send(1, 1, frame, cmd, 0, 0, p1, p2, p3, p4, x, y, z)
    end = time.time() + timeout
    while time.time() < end:
        msg = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.1)
        if msg is not None and msg.command == cmd:
            return g.result_name(msg.result)
    return None


def cmd_auto(args):
    m = g.connect(args)
    if g.wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    out = {}
    param_set(m, "RTL_RETURN_ALT", args.rtl_alt)
    out["takeoff_disarmed"], _ = g.command(m, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN,
                                           NAN, HOME_ALT + args.alt)
    out["arm"], _ = g.command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out["takeoff"], _ = g.command(m, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN,
                                  HOME_ALT + args.alt)
    out["loiter_after_takeoff"] = wait_mode(m, 4, 3, armed=True, timeout=30) is not None
    time.sleep(1.0)
    lp = local_position(m)
    out["after_takeoff_ned"] = [lp.x, lp.y, lp.z]
    lat, lon = latlon(args.north, args.east)
    out["reposition_int"] = command_int(m, mavlink2.MAV_CMD_DO_REPOSITION, p1=-1, p2=1, p4=NAN,
                                        x=lat, y=lon, z=args.alt)
    end = time.time() + 20
    while time.time() < end:
        send_pump(m)
        lp = local_position(m)
        if lp and math.dist((lp.x, lp.y, lp.z), (args.north, args.east, -args.alt)) < 0.05:
            break
    out["after_reposition_ned"] = [lp.x, lp.y, lp.z]
    out["hold"], _ = g.command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 4, 3)
    time.sleep(1.0)
    lp = local_position(m)
    out["after_hold_ned"] = [lp.x, lp.y, lp.z]
    out["request_message_int"] = command_int(m, mavlink2.MAV_CMD_REQUEST_MESSAGE, p1=242)
    home = m.recv_match(type="HOME_POSITION", blocking=True, timeout=2)
    out["home"] = None if home is None else [home.latitude, home.longitude, home.altitude,
                                             home.x, home.y, home.z]
    out["rtl"], _ = g.command(m, mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    max_alt = [0.0]

    def watch(msg):
        if msg.get_type() == "LOCAL_POSITION_NED":
            max_alt[0] = max(max_alt[0], -msg.z)

    out["rtl_disarmed"] = wait_disarmed(m, timeout=60, watch=watch) is not None
    out["rtl_max_alt"] = max_alt[0]
    lp = local_position(m)
    out["after_rtl_ned"] = [lp.x, lp.y, lp.z]
    out["arm_again"], _ = g.command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out["land"], _ = g.command(m, mavlink2.MAV_CMD_NAV_LAND)
    out["land_disarmed"] = wait_disarmed(m, timeout=30) is not None
    out["unsupported_int"] = command_int(m, mavlink2.MAV_CMD_DO_SET_SERVO, p1=1, p2=1500)
    return out


def lockstep(m, send, ticks, on_odometry=None):
    """Sends a setpoint per tick and waits for the tick's ODOMETRY; returns the last one."""
    t_us = 0
    last = None
    for _ in range(ticks):
        send(last)
        end = time.time() + 2
        got = None
        while time.time() < end:
            msg = m.recv_match(type=["ODOMETRY", "ATTITUDE_QUATERNION"], blocking=True,
                               timeout=0.2)
            if msg is None:
                continue
            if msg.get_type() == "ATTITUDE_QUATERNION":
                if on_odometry is not None:
                    on_odometry(msg)
                continue
            if msg.time_usec > t_us:
                got = msg
                break
        if got is None:
            return last, "no ODOMETRY for a setpoint"
        t_us = got.time_usec
        last = got
    return last, None


def start_offboard(m, send):
    for _ in range(5):
        send(None)
        time.sleep(0.05)
    a, _ = g.command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 6, 0)
    for _ in range(3):
        send(None)
        time.sleep(0.05)
    b, _ = g.command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    return a, b


def cmd_position(args):
    m = g.connect(args)
    if g.wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    out = {}
    n, e, d = args.target
    mask = (mavlink2.POSITION_TARGET_TYPEMASK_VX_IGNORE | mavlink2.POSITION_TARGET_TYPEMASK_VY_IGNORE
            | mavlink2.POSITION_TARGET_TYPEMASK_VZ_IGNORE | mavlink2.POSITION_TARGET_TYPEMASK_AX_IGNORE
            | mavlink2.POSITION_TARGET_TYPEMASK_AY_IGNORE | mavlink2.POSITION_TARGET_TYPEMASK_AZ_IGNORE
            | mavlink2.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE)

    def send(_last):
        m.mav.set_position_target_local_ned_send(0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, mask, n, e,
                                                 d, NAN, NAN, NAN, NAN, NAN, NAN, 0.0, NAN)

    out["offboard"], out["arm"] = start_offboard(m, send)
    last, err = lockstep(m, send, args.ticks)
    if err:
        out["error"] = err
    out["final_ned"] = None if last is None else [last.x, last.y, last.z]
    out["final_speed"] = None if last is None else math.sqrt(last.vx ** 2 + last.vy ** 2
                                                             + last.vz ** 2)
    out["error_m"] = None if last is None else math.dist((last.x, last.y, last.z), (n, e, d))
    g.command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    return out


def raw_v2(msgid, crc_extra, payload, seq=0, sysid=255, compid=190):
    while len(payload) > 1 and payload[-1] == 0:
        payload = payload[:-1]
    header = bytes([0xFD, len(payload), 0, 0, seq & 0xFF, sysid, compid, msgid & 0xFF,
                    (msgid >> 8) & 0xFF, (msgid >> 16) & 0xFF])
    crc = x25crc(header[1:] + payload)
    crc.accumulate(bytes([crc_extra]))
    return header + payload + struct.pack("<H", crc.crc)


def attitude_target_raw(q, rates, thrust, thrust_body, type_mask, seq=0):
    payload = struct.pack("<I4f4fBBB3f", 0, *q, *rates, thrust, 1, 1, type_mask, *thrust_body)
    return raw_v2(82, 49, payload, seq)


def cmd_attitude(args):
    m = g.connect(args)
    if g.wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    out = {}
    q = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))  # level, facing east
    hover = args.hover_thrust
    seq = [0]
    first = m.recv_match(type="ODOMETRY", blocking=True, timeout=2)

    def send(last):
        # thrust_body FRD: forward (east) --forward, hold altitude with a PD on z.
        z = hover
        if last is not None:
            z = hover * (1 + (4.0 * (last.z - first.z) + 3.0 * last.vz) / 9.81)
        frame = attitude_target_raw(q, (0, 0, 0), 0.0, (args.forward, 0.0, -z),
                                    32 | 7, seq[0])  # THRUST_BODY_SET | rates ignored
        seq[0] += 1
        m.write(frame)

    max_tilt = [0.0]

    def att(msg):
        max_tilt[0] = max(max_tilt[0], g.tilt_deg((msg.q1, msg.q2, msg.q3, msg.q4)))

    out["offboard"], out["arm"] = start_offboard(m, send)
    last, err = lockstep(m, send, args.ticks, att)
    if err:
        out["error"] = err
    out["start_ned"] = [first.x, first.y, first.z]
    out["final_ned"] = None if last is None else [last.x, last.y, last.z]
    out["final_velocity_ned"] = None if last is None else [last.vx, last.vy, last.vz]
    out["max_tilt_deg"] = max_tilt[0]
    g.command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    return out


def cmd_rates(args):
    m = g.connect(args)
    if g.wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    out = {}
    q = (1.0, 0.0, 0.0, 0.0)
    hover = args.hover_thrust
    state = {"roll": 0.0}
    ignore_att = mavlink2.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE

    def send_with(rate):
        def send(_last):
            m.mav.set_attitude_target_send(0, 1, 1, ignore_att, q, rate, 0.0, 0.0, hover)
        return send

    def att(msg):
        state["roll"] = max(state["roll"], abs(msg.rollspeed))

    out["offboard"], out["arm"] = start_offboard(m, send_with(0.0))
    results = {}
    # Short bursts there and back (a long roll would flip the vehicle): at the default limit
    # (MC_ROLLRATE_MAX 220 deg/s), then at 90 deg/s set over the parameter protocol.
    for label, rate, limit in (("50", 50.0, None), ("1e30", 1e30, 90.0)):
        if limit is not None:
            param_set(m, "MC_ROLLRATE_MAX", limit)
        state["roll"] = 0.0
        err = None
        for sign in (1.0, -1.0, 1.0, -1.0):
            last, e = lockstep(m, send_with(sign * rate), args.ticks, att)
            err = err or e
            if last is not None:
                state["roll"] = max(state["roll"], abs(last.rollspeed))
        results[label] = {"max_roll_rate": state["roll"], "error": err}
    # NaN: refused (not a tick) — the twin does not step, so no new ODOMETRY comes.
    before = m.recv_match(type="ODOMETRY", blocking=True, timeout=1)
    for _ in range(10):
        m.mav.set_attitude_target_send(0, 1, 1, ignore_att, q, NAN, 0.0, 0.0, hover)
    texts = []
    end = time.time() + 0.5
    while time.time() < end:
        msg = m.recv_match(type="STATUSTEXT", blocking=True, timeout=0.1)
        if msg is not None:
            texts.append(msg.text)
    results["nan"] = {"texts": texts, "t_before": before.time_usec if before else None}
    out["results"] = results
    g.command(m, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    return out


def cmd_actuator_off(args):
    m = g.connect(args)
    if g.wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    out = {}
    texts = []
    for _ in range(5):
        m.mav.set_actuator_control_target_send(0, 0, 1, 1, [0.5] * 8)
        time.sleep(0.05)
    end = time.time() + 1.0
    while time.time() < end:
        msg = m.recv_match(type="STATUSTEXT", blocking=True, timeout=0.1)
        if msg is not None:
            texts.append(msg.text)
    out["texts"] = texts
    out["offboard"], _ = g.command(m, mavlink2.MAV_CMD_DO_SET_MODE, 1, 6, 0)
    # The arm group is taken (not counted as rejected input: the test reads the exit line).
    m.mav.set_actuator_control_target_send(0, 2, 1, 1, [1.0] + [0.0] * 7)
    time.sleep(0.3)
    return out


def cmd_v1(args):
    os.environ.pop("MAVLINK20", None)
    from pymavlink.dialects.v10 import common as mavlink1
    m = mavutil_v1(args)
    end = time.time() + 10
    hb = None
    while time.time() < end and hb is None:
        m.mav.heartbeat_send(mavlink1.MAV_TYPE_GCS, mavlink1.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=0.3)
    out = {"heartbeat": hb is not None,
           "heartbeat_v1": hb is not None and hb.get_msgbuf()[0] == 0xFE}
    m.mav.command_long_send(1, 1, mavlink1.MAV_CMD_REQUEST_MESSAGE, 0, 242, 0, 0, 0, 0, 0, 0)
    ack = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=3)
    out["ack"] = None if ack is None else g.result_name(ack.result)
    out["ack_v1"] = ack is not None and ack.get_msgbuf()[0] == 0xFE
    seen = set()
    end = time.time() + 1.5
    while time.time() < end:
        msg = m.recv_match(blocking=True, timeout=0.1)
        if msg is not None and msg.get_type() != "BAD_DATA":
            seen.add((msg.get_type(), msg.get_msgbuf()[0]))
    out["v2_frames_seen"] = sorted(t for t, stx in seen if stx == 0xFD)
    out["v1_types_seen"] = sorted(t for t, stx in seen if stx == 0xFE)
    return out


def mavutil_v1(args):
    from pymavlink import mavutil
    from pymavlink.dialects.v10 import common as mavlink1
    m = mavutil.mavlink_connection(args.connect, source_system=255, source_component=190,
                                   dialect="common")
    m.mav = mavlink1.MAVLink(m, srcSystem=255, srcComponent=190)
    m.WIRE_PROTOCOL_VERSION = "1.0"
    return m


def cmd_fuzz(args):
    m = g.connect(args)
    if g.wait_heartbeat(m) is None:
        return {"error": "no heartbeat"}
    rng = random.Random(args.seed)
    out = {}
    lp0 = local_position(m)
    out["before_ned"] = [lp0.x, lp0.y, lp0.z]
    mav = m.mav
    bad_values = [NAN, INF, -INF, 1e30, -1e30, 3.4e38]

    def pick():
        return rng.choice(bad_values)

    def pack(msg):
        return msg.pack(mav)

    kinds = {"random": 0, "garbled": 0, "truncated": 0, "v1": 0, "unknown_id": 0, "valued": 0}
    builders = [
        lambda: mavlink2.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, rng.choice([1, 7, 8, 9, 12]), rng.randrange(0, 4096),
            *[pick() if rng.random() < 0.5 else rng.uniform(-1e6, 1e6) for _ in range(11)]),
        lambda: mavlink2.MAVLink_set_attitude_target_message(
            0, 1, 1, rng.randrange(0, 256), [pick() for _ in range(4)], pick(), pick(), pick(),
            pick()),
        lambda: mavlink2.MAVLink_param_set_message(1, 1, rng.choice(
            [b"COM_OF_LOSS_T", b"MPC_XY_VEL_MAX", b"COM_OBL_RC_ACT", b"MC_ROLLRATE_MAX"]), pick(),
            rng.choice([6, 9])),
        lambda: mavlink2.MAVLink_param_request_read_message(1, 1, b"X" * 16,
                                                            rng.randrange(-32768, 32767)),
        lambda: mavlink2.MAVLink_mission_count_message(1, 1, rng.randrange(0, 65536),
                                                       rng.choice([0, 1, 2, 255])),
        lambda: mavlink2.MAVLink_mission_item_int_message(
            1, 1, rng.randrange(0, 5), rng.choice([0, 3, 5, 6, 1, 2]), rng.choice([16, 21, 22, 178,
                                                                                    20, 999]),
            0, 1, pick(), pick(), pick(), pick(), rng.randrange(-2**31, 2**31),
            rng.randrange(-2**31, 2**31), pick(), 0),
        lambda: mavlink2.MAVLink_command_int_message(
            1, 1, rng.choice([0, 3, 5, 6, 1]), rng.choice([22, 192, 20, 21, 178, 300, 224, 512]), 0,
            0, pick(), pick(), pick(), pick(), rng.randrange(-2**31, 2**31),
            rng.randrange(-2**31, 2**31), pick()),
        lambda: mavlink2.MAVLink_command_long_message(
            1, 1, rng.choice([22, 192, 20, 178, 300, 224, 512, 511]), 0, *[pick() for _ in range(7)]),
        lambda: mavlink2.MAVLink_mission_set_current_message(1, 1, rng.randrange(0, 65536)),
        lambda: mavlink2.MAVLink_set_actuator_control_target_message(
            0, rng.randrange(0, 4), 1, 1, [pick() for _ in range(8)]),
    ]
    for i in range(args.frames):
        kind = rng.choice(list(kinds))
        kinds[kind] += 1
        if kind == "random":
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300)))
        elif kind == "valued":
            data = pack(rng.choice(builders)())
        elif kind == "garbled":
            data = bytearray(pack(rng.choice(builders)()))
            j = rng.randrange(len(data))
            data[j] ^= 1 << rng.randrange(8)
            data = bytes(data)
        elif kind == "truncated":
            data = pack(rng.choice(builders)())
            data = data[:rng.randrange(1, len(data))]
        elif kind == "unknown_id":
            data = raw_v2(rng.choice([9999, 60000, 12345]), 0,
                          bytes(rng.randrange(256) for _ in range(10)), i)
        else:  # v1: a valid MAVLink 1 frame (header + CRC), random payload of a real message
            msgid = rng.choice([0, 76, 82, 84, 23, 21, 39, 44, 73])
            payload = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 40)))
            body = bytes([len(payload), i & 0xFF, 255, 190, msgid]) + payload
            crc = x25crc(body)
            crc.accumulate(bytes([mavlink2.mavlink_map[msgid].crc_extra]))
            data = bytes([0xFE]) + body + struct.pack("<H", crc.crc)
        m.write(data)
        if i % 50 == 0:
            # Drain, so the socket buffer keeps up.
            while m.recv_match(blocking=False) is not None:
                pass
    out["sent"] = kinds
    time.sleep(0.5)
    while m.recv_match(blocking=False) is not None:
        pass
    # Still serving, the vehicle where it was, nothing changed by the garbage.
    res, _ = g.command(m, mavlink2.MAV_CMD_REQUEST_MESSAGE, 148)
    out["ack_after"] = res
    hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=3)
    out["armed_after"] = bool(hb.base_mode & 128) if hb else None
    out["mode_after"] = list(mode_of(hb)) if hb else None
    lp = local_position(m)
    out["after_ned"] = [lp.x, lp.y, lp.z]
    m.mav.param_request_list_send(1, 1)
    values = {}
    end = time.time() + 3
    while time.time() < end:
        msg = m.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
        if msg is None:
            if values:
                break
            continue
        values[msg.param_id] = msg.param_value if msg.param_type != 6 else param_int_value(
            msg.param_value)
    out["params_after"] = values
    m.mav.mission_request_list_send(1, 1, 0)
    cnt = m.recv_match(type="MISSION_COUNT", blocking=True, timeout=2)
    out["mission_count_after"] = None if cnt is None else cnt.count
    st = m.recv_match(type="SYS_STATUS", blocking=True, timeout=3)
    out["errors_comm"] = None if st is None else st.errors_comm
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("mode", choices=["params", "mission", "auto", "position", "attitude", "rates",
                                    "actuator", "v1", "fuzz"])
    p.add_argument("--connect", required=True)
    p.add_argument("--takeoff-alt", type=float, default=1.8)
    p.add_argument("--alt", type=float, default=1.5)
    p.add_argument("--rtl-alt", type=float, default=2.0)
    p.add_argument("--north", type=float, default=1.0)
    p.add_argument("--east", type=float, default=0.5)
    p.add_argument("--target", type=float, nargs=3, default=[0.5, -0.3, -1.5])
    p.add_argument("--ticks", type=int, default=600)
    p.add_argument("--hover-thrust", type=float, default=0.5)
    p.add_argument("--forward", type=float, default=0.02)
    p.add_argument("--timeout", type=float, default=60.0)
    p.add_argument("--frames", type=int, default=3000)
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    fn = {"params": cmd_params, "mission": cmd_mission, "auto": cmd_auto,
          "position": cmd_position, "attitude": cmd_attitude, "rates": cmd_rates,
          "actuator": cmd_actuator_off, "v1": cmd_v1,
          "fuzz": cmd_fuzz}[args.mode]
    print(json.dumps(fn(args)))


if __name__ == "__main__":
    main()
