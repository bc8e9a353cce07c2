#!/usr/bin/env python3
"""MAVSDK (PyPI `mavsdk`, the gRPC API; venv: scripts/setup-mavsdk.sh) flies the twin's
autopilot as it flies a PX4 vehicle. Opt-in, not in CI.

  amstack twin serve --mavlink udp:127.0.0.1:14540 --platform fa-hexa --realtime &
  PY=$(bash scripts/setup-mavsdk.sh)
  $PY scripts/mavsdk-check.py --connect udpout://127.0.0.1:14540

Checks, in order: connection; health_all_ok and is_armable; parameters through MAVSDK's
action plugin (takeoff and RTL altitude); arm and takeoff; goto (DO_REPOSITION); offboard
position (SET_POSITION_TARGET_LOCAL_NED) to a point; a mission of three waypoints (uploaded,
started, finished); RTL (lands and disarms). Prints one line per step and a JSON summary;
exits 1 if a step failed.
"""

import argparse
import asyncio
import json
import math
import sys
import time
import warnings

warnings.filterwarnings("ignore", category=FutureWarning)
from mavsdk import System  # noqa: E402
from mavsdk.mission import MissionItem, MissionPlan  # noqa: E402
from mavsdk.offboard import OffboardError, PositionNedYaw  # noqa: E402

EARTH_R = 6371000.0


def offset(lat, lon, north, east):
    return (lat + math.degrees(north / EARTH_R),
            lon + math.degrees(east / (EARTH_R * math.cos(math.radians(lat)))))


async def first(aiter):
    async for x in aiter:
        return x


async def wait_for(aiter, pred, timeout):
    async def run():
        async for x in aiter:
            if pred(x):
                return x
    return await asyncio.wait_for(run(), timeout)


async def position_ned(drone):
    p = await first(drone.telemetry.position_velocity_ned())
    return p.position.north_m, p.position.east_m, p.position.down_m


async def main(args):
    results = {}
    t0 = time.time()

    def step(name, ok, detail=""):
        results[name] = {"ok": bool(ok), "detail": detail}
        print(f"[{time.time() - t0:6.1f} s] {'OK  ' if ok else 'FAIL'} {name}: {detail}",
              flush=True)

    drone = System()
    await drone.connect(system_address=args.connect)
    state = await wait_for(drone.core.connection_state(), lambda s: s.is_connected, 20)
    step("connect", state.is_connected, args.connect)

    try:
        health = await wait_for(drone.telemetry.health(),
                                lambda h: h.is_global_position_ok and h.is_home_position_ok, 20)
        all_ok = await wait_for(drone.telemetry.health_all_ok(), lambda ok: ok, 10)
        step("health_all_ok", all_ok, str(health).replace("\n", " "))
        step("is_armable", health.is_armable, "")
    except asyncio.TimeoutError:
        h = await first(drone.telemetry.health())
        step("health_all_ok", False, str(h).replace("\n", " "))

    await drone.action.set_takeoff_altitude(args.alt)
    takeoff_alt = await drone.action.get_takeoff_altitude()
    await drone.action.set_return_to_launch_altitude(args.alt + 0.5)
    rtl_alt = await drone.action.get_return_to_launch_altitude()
    step("parameters", abs(takeoff_alt - args.alt) < 1e-3 and abs(rtl_alt - args.alt - 0.5) < 1e-3,
         f"MIS_TAKEOFF_ALT {takeoff_alt:.2f} m, RTL_RETURN_ALT {rtl_alt:.2f} m")
    gps = await first(drone.telemetry.gps_info())
    home = await first(drone.telemetry.home())
    step("gps_info and home", gps.num_satellites > 0,
         f"{gps.num_satellites} satellites, {gps.fix_type}; home {home.latitude_deg:.7f}, "
         f"{home.longitude_deg:.7f}, {home.absolute_altitude_m:.2f} m")

    await drone.action.arm()
    await drone.action.takeoff()
    pos = await wait_for(drone.telemetry.position(),
                         lambda p: abs(p.relative_altitude_m - args.alt) < 0.2, 30)
    step("takeoff", True, f"relative altitude {pos.relative_altitude_m:.2f} m")

    lat, lon = offset(home.latitude_deg, home.longitude_deg, 1.0, 0.5)
    await drone.action.goto_location(lat, lon, home.absolute_altitude_m + args.alt, float("nan"))
    n0, e0 = 1.0, 0.5

    def near(n, e, d, tol):
        return lambda pv: math.dist((pv.position.north_m, pv.position.east_m, pv.position.down_m),
                                    (n, e, d)) < tol
    home_ned = await position_ned(drone)
    try:
        await wait_for(drone.telemetry.position_velocity_ned(), near(n0, e0, -args.alt, 0.1), 30)
        step("goto", True, f"at {tuple(round(x, 3) for x in await position_ned(drone))}")
    except asyncio.TimeoutError:
        step("goto", False, f"at {await position_ned(drone)}")

    target = (0.5, 1.0, -args.alt)
    await drone.offboard.set_position_ned(PositionNedYaw(*target, 90.0))
    try:
        await drone.offboard.start()
        await wait_for(drone.telemetry.position_velocity_ned(), near(*target, 0.05), 30)
        await asyncio.sleep(1.0)
        p = await position_ned(drone)
        step("offboard position", math.dist(p, target) < 0.05,
             f"at {tuple(round(x, 3) for x in p)}, error {math.dist(p, target):.3f} m")
        await drone.offboard.stop()
    except (OffboardError, asyncio.TimeoutError) as e:
        step("offboard position", False, str(e))

    items = []
    for n, e in ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0)):
        la, lo = offset(home.latitude_deg, home.longitude_deg, n, e)
        items.append(MissionItem(la, lo, args.alt, 1.0, False, float("nan"), float("nan"),
                                 MissionItem.CameraAction.NONE, float("nan"), float("nan"), 0.1,
                                 float("nan"), float("nan"), MissionItem.VehicleAction.NONE))
    await drone.mission.upload_mission(MissionPlan(items))
    await drone.mission.start_mission()
    try:
        progress = await wait_for(drone.mission.mission_progress(),
                                  lambda m: m.current == m.total, 60)
        finished = await drone.mission.is_mission_finished()
        step("mission", finished, f"progress {progress.current}/{progress.total}")
    except asyncio.TimeoutError:
        step("mission", False, "not finished")

    await drone.action.return_to_launch()
    try:
        await wait_for(drone.telemetry.armed(), lambda a: not a, 60)
        p = await position_ned(drone)
        step("RTL", True, f"disarmed at {tuple(round(x, 3) for x in p)} (armed at "
                          f"{tuple(round(x, 3) for x in home_ned[:2])})")
    except asyncio.TimeoutError:
        step("RTL", False, "not disarmed")

    ok = all(r["ok"] for r in results.values())
    print(json.dumps({"ok": ok, "steps": results}))
    return 0 if ok else 1


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--connect", default="udpout://127.0.0.1:14540")
    p.add_argument("--alt", type=float, default=1.5)
    sys.exit(asyncio.run(main(p.parse_args())))
