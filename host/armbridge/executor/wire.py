"""The messages between a RemoteClient (the caller's thread) and its Engine, as JSON lines.

An engine in a thread of this process hands its messages over as Python objects
(executor/remote.py's ThreadLink); one in a child process (ProcessLink) sends
them over a socket, one JSON object a line, encoded and decoded here. Nothing is
pickled: what crosses is data (numbers, strings, lists), rebuilt on arrival
into the types the callers know (P.Telemetry with numpy arrays, P.Event,
BoardInfo, LinkStats, the project's exceptions).

Messages (a dict with "k", the kind):

    caller -> engine    call {id, name, args, kw}   run client.<name>(*args, **kw)
                        idle {resync}               how to serve the link between calls
                        abort                       end the running call (Aborted)
                        estop                       the e-stop byte at once, then abort
                        hold {on}                   HOLD (true) / RESUME (false) at execute's next turn
                        close                       stop serving; the engine closes the port
    engine -> caller    tel {t, m, mirror}          on_telemetry(t, m)
                        ev {t, m, mirror}           on_event(t, m)
                        err {t, text, mirror}       on_error(t, text)
                        progress {n, mirror}        execute()'s on_progress(n)
                        ret {id, value, snap}       the call returned value
                        exc {id, error, snap}       the call raised error

`mirror`: the few fields the caller reads while a call runs (state, last
event, FAULT reason, done index); `snap`: everything the caller reads after
one (adds the board's info, the link statistics, done and start times).
"""
from __future__ import annotations

import dataclasses
import json
from typing import Any

import numpy as np

from armbridge.errors import ArmbridgeError
from armbridge.link import protocol as P
from armbridge.link.stats import LinkStats


class Aborted(ArmbridgeError):
    """The running call was ended by the caller (an e-stop, or a call left by an interruption)."""


class EngineFailed(ArmbridgeError):
    """The engine raised something that is not one of the project's errors (a bug): its
    type and message, and where it came from."""


def mirror(client: Any) -> dict[str, Any]:
    return {"state": client.state, "last_event": client.last_event, "fault_reason": client.fault_reason,
            "done_index": client.done_index}


def snapshot(client: Any) -> dict[str, Any]:
    """What the caller reads of `client` after a call (copies: the engine runs on)."""
    info = client.info
    return {**mirror(client), "connected": bool(client.connected), "session": client.session,
            "info": dataclasses.asdict(info) if info is not None else None,
            "stats": dataclasses.asdict(client.stats),
            "done_times": dict(client.done_times), "start_times": dict(client.start_times)}


def restore_snapshot(snap: dict[str, Any]) -> dict[str, Any]:
    """A snapshot that crossed as JSON, back into its types (int keys, BoardInfo, LinkStats)."""
    from armbridge.executor.handshake import BoardInfo

    out = dict(snap)
    if snap.get("info") is not None and not isinstance(snap["info"], BoardInfo):
        info = dict(snap["info"])
        info["limits_milli"] = [tuple(x) for x in info.get("limits_milli", [])]
        out["info"] = BoardInfo(**info)
    if isinstance(snap.get("stats"), dict):
        out["stats"] = LinkStats(**snap["stats"])
    for key in ("done_times", "start_times"):
        out[key] = {int(i): float(t) for i, t in snap.get(key, {}).items()}
    return out


# --------------------------------------------------------------------- JSON lines

def _board_line(m: Any) -> dict[str, Any]:
    if isinstance(m, P.Telemetry):
        return {"type": "T", "bseq": m.bseq, "ms": m.ms, "state": m.state, "done": m.done, "free": m.free,
                "q": m.q.tolist(), "target": m.target.tolist(), "effort": m.effort.tolist(),
                "extra": list(m.extra)}
    if isinstance(m, P.Event):
        return {"type": "EV", "bseq": m.bseq, "ms": m.ms, "kind": m.kind, "args": list(m.args)}
    raise TypeError(f"not a board line: {m!r}")


def _board_line_back(d: dict[str, Any]) -> Any:
    if d["type"] == "T":
        return P.Telemetry(d["bseq"], d["ms"], d["state"], d["done"], d["free"], np.asarray(d["q"], float),
                           np.asarray(d["target"], float), np.asarray(d["effort"], float), tuple(d["extra"]))
    return P.Event(d["bseq"], d["ms"], d["kind"], tuple(d["args"]))


_ERRORS: dict[str, type[BaseException]] = {}


def _error_classes() -> dict[str, type[BaseException]]:
    if not _ERRORS:
        from armbridge import errors
        from armbridge.link import transport

        for mod in (errors, transport):
            for name in dir(mod):
                obj = getattr(mod, name)
                if isinstance(obj, type) and issubclass(obj, ArmbridgeError):
                    _ERRORS[name] = obj
        _ERRORS["Aborted"] = Aborted
    return _ERRORS


def error_to_json(exc: BaseException) -> dict[str, Any]:
    return {"type": type(exc).__name__, "message": str(exc), "usage": getattr(exc, "usage", None)}


def error_from_json(d: dict[str, Any]) -> BaseException:
    cls = _error_classes().get(d["type"])
    if cls is None:
        return EngineFailed(f"the link engine failed: {d['type']}: {d['message']}")
    if d.get("usage") is not None:
        try:
            return cls(d["message"], usage=bool(d["usage"]))  # type: ignore[call-arg]
        except TypeError:
            pass
    try:
        return cls(d["message"])
    except TypeError:
        return ArmbridgeError(d["message"])


def _jsonable(v: Any) -> Any:
    if isinstance(v, (P.Ok, P.Er)):
        return {"__answer__": type(v).__name__, **dataclasses.asdict(v)}
    if isinstance(v, np.ndarray):
        return {"__array__": v.tolist()}
    if isinstance(v, tuple):
        return {"__tuple__": [_jsonable(x) for x in v]}
    if isinstance(v, list):
        return [_jsonable(x) for x in v]
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return dataclasses.asdict(v)
    return v


def _from_jsonable(v: Any) -> Any:
    if isinstance(v, dict) and "__answer__" in v:
        d = dict(v)
        cls = P.Ok if d.pop("__answer__") == "Ok" else P.Er
        for key in ("payload", "detail"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**d)
    if isinstance(v, dict) and "__array__" in v:
        return np.asarray(v["__array__"], float)
    if isinstance(v, dict) and "__tuple__" in v:
        return tuple(_from_jsonable(x) for x in v["__tuple__"])
    if isinstance(v, list):
        return [_from_jsonable(x) for x in v]
    return v


def encode(msg: dict[str, Any]) -> bytes:
    """One message as a JSON line (board lines, errors and answers turned into data)."""
    out = dict(msg)
    if "m" in out:
        out["m"] = _board_line(out["m"])
    if "error" in out:
        out["error"] = error_to_json(out["error"])
    for key in ("value", "args"):
        if key in out:
            out[key] = _jsonable(out[key])
    if "kw" in out:
        out["kw"] = {k: _jsonable(v) for k, v in out["kw"].items()}
    return json.dumps(out, separators=(",", ":")).encode() + b"\n"


def decode(line: bytes) -> dict[str, Any]:
    msg = json.loads(line)
    if "m" in msg:
        msg["m"] = _board_line_back(msg["m"])
    if "error" in msg:
        msg["error"] = error_from_json(msg["error"])
    for key in ("value", "args"):
        if key in msg:
            msg[key] = _from_jsonable(msg[key])
    if "kw" in msg:
        msg["kw"] = {k: _from_jsonable(v) for k, v in msg["kw"].items()}
    if msg.get("snap") is not None:
        msg["snap"] = restore_snapshot(msg["snap"])
    return msg
