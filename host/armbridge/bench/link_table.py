"""The table `armbridge bench link` prints (rich), for either board of bench/link.py."""
from __future__ import annotations

TARGET_WPS = 300  # sustained 3-joint waypoints/s
TARGET_ESTOP_MS = 20.0  # e-stop byte written -> outputs off, worst case


def print_result(r: dict, console) -> None:
    """The MicroPython board's table has v1 beside v2 (the damage model); the pump board's
    one column of v2 and the Modbus round trip."""
    from rich.table import Table

    tp, rt, es, so = r["throughput"], r["round_trip"], r["estop"], r.get("soak")
    ud = r.get("undetected")
    board = r.get("board", "esp32")
    load = f", {r['busy_processes']} busy processes beside" if r.get("busy_processes") else ""
    table = Table(title=f"armbridge bench link --board {board} (115200 baud 8N1, 3-joint waypoints, "
                        f"{r.get('clock', 'wall')} clock{load})")
    table.add_column("measure", justify="left")
    cols = ("v1 (CRC-16)", "v2 (CRC-32, epoch)", "target") if ud else (f"{board} (v2)", "target")
    for col in cols:
        table.add_column(col, justify="right")

    def row(name: str, v1: str, v2: str, target: str = "") -> None:
        table.add_row(name, v1, v2, target) if ud else table.add_row(name, v2, target)

    def rate(u: dict) -> str:
        return (f"{u['undetected']} / {u['damaged']:,} = {u['rate']:.2g}" if u["undetected"]
                else f"0 / {u['damaged']:,} (< {u['rate_upper_95']:.1g}, 95 %)")

    if ud:
        row("undetected errors / damaged lines", rate(ud["v1"]), rate(ud["v2"]), "v2: 0")
    row("sustained waypoints/s (median run)", f"({tp['v1_line_rate_ceiling_wps']:.0f} ceiling)",
        f"{tp['waypoints_per_s']:.0f}", f">= {TARGET_WPS}")
    row("line capacity used (host->board)", "", f"{tp['line_capacity_used']:.1%}")
    row("bytes per waypoint (W line / all bytes)", f"{tp['v1_w_line_bytes']:.1f} / -",
        f"{tp['w_line_bytes']:.1f} / {tp['bytes_per_waypoint']:.1f}")
    row("line-rate ceiling for these W lines (wp/s)", f"{tp['v1_line_rate_ceiling_wps']:.0f}",
        f"{tp['line_rate_ceiling_wps']:.0f}")
    row("streaming: W resent / PINGs / timeouts (spurious) / slowed", "",
        f"{tp['retransmitted']} / {tp['pings']} / {tp['timeouts']} ({tp['spurious_timeouts']}) / "
        f"{tp['slow_events']}")
    row("ack round trip median / p95 (ms)", "", f"{rt['median_ms']:.2f} / {rt['p95_ms']:.2f}")
    row("e-stop byte -> outputs off median / max (ms)", "",
        f"{es['byte_to_outputs_off']['median_ms']:.2f} / {es['byte_to_outputs_off']['max_ms']:.2f}",
        f"< {TARGET_ESTOP_MS:g}")
    row("e-stop byte -> ESTOP event at host median / max (ms)", "",
        f"{es['byte_to_event_at_host']['median_ms']:.2f} / {es['byte_to_event_at_host']['max_ms']:.2f}")
    if so is not None:
        row(f"soak {so['seconds']:.0f} s: waypoints executed", "", f"{so['executed']} / {so['waypoints']}")
        row("soak: lost / duplicated / wrong value / in order", "",
            f"{so['lost']} / {so['duplicated']} / {so['wrong_value']} / {so['in_order']}", "0 / 0 / 0 / True")
        row("soak: resets / resyncs / W resent / line errors", "",
            f"{so['resets']} / {so['resyncs']} / {so['retransmitted']} / {so['line_errors']}")
    mb = r.get("modbus")
    if mb:
        for key, what in (("read_one", "one register (FC4)"), ("write_setpoints", "set-point write (FC16 x 3)")):
            m = mb[key]
            row(f"Modbus {what} median / p95 / min (ms)", "",
                f"{m['median_ms']:.2f} / {m['p95_ms']:.2f} / {m['min_ms']:.2f}")
        row("Modbus: floor read / write; retries / timeouts", "",
            f"{mb['wire_read_ms']:.2f} / {mb['wire_write_ms']:.2f} ms; {mb['retries']} / {mb['timeouts']}")
    console.print(table)
    if r.get("targets"):
        console.print("targets: " + ", ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in r["targets"].items()))
