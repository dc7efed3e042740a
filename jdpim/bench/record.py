"""The record every benchmark writes beside its results: date, machine, versions, load and protocol."""

from __future__ import annotations

import datetime
import json
import os
import pathlib
import platform


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else ``platform.processor()``; ``"unknown"`` if neither)."""
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def record(protocol: str) -> dict:
    """Date (UTC), machine, versions, load average (1, 5, 15 min, now) and the timing ``protocol`` of a benchmark.

    Call it when the measurements end, so that the load average covers them.
    """
    import jax

    from .._cpu import usable_cores
    from .._io import versions

    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": {
            "cpu": cpu_model(),
            "cores": usable_cores(),
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "backend": jax.default_backend(),
            "devices": [d.device_kind for d in jax.local_devices()],
        },
        "versions": {k: v for k, v in versions().items() if k not in ("backend", "devices")},
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "protocol": protocol,
    }


def record_lines(rec: dict) -> list[str]:
    """The record as the Markdown lines that head every benchmark's ``.md`` (a ``note`` included where present)."""
    m, v = rec["machine"], rec["versions"]
    devices = m["devices"]
    if isinstance(devices, list):
        devices = f"{len(devices)} x {devices[0]}" if devices else "no devices"
    versions = ", ".join(f"{k} {v[k]}" for k in ("python", "jax", "numpy", "jdpim"))
    return [
        f"Measured {rec['date']}; CPU: {m['cpu']}, {m['cores']} usable cores of {m['cpu_count']}; {m['backend']}, "
        f"devices: {devices}; {versions}; load average (1, 5, 15 min) at the end: {rec['load_average']}.",
        "",
        f"Protocol: {rec['protocol']}.",
        "",
        *([f"Note: {rec['note']}.", ""] if "note" in rec else []),
    ]


def table_lines(rows: list[dict], cols: list[str]) -> list[str]:
    """Markdown lines of ``rows`` in the columns ``cols``; a missing or ``None`` value is an empty cell."""
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    return lines + ["| " + " | ".join("" if r.get(c) is None else str(r[c]) for c in cols) + " |" for r in rows]


def write_record(out: pathlib.Path, name: str, info: dict, lines: list[str], *, log=print) -> list[str]:
    """Write ``info`` to ``out/name.json`` and ``lines`` to ``out/name.md`` (folders made as needed), log the Markdown
    and return the two file names."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(info, indent=1) + "\n")
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    log("\n".join(lines))
    return [f"{name}.json", f"{name}.md"]
