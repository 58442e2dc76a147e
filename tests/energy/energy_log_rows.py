"""Helpers for the energy tests: rows of small run logs (a unique module name, so that
``from energy_log_rows import ...`` cannot pick up another test folder's conftest)."""

from __future__ import annotations

COLUMNS = ("t", "frame", "v_host", "v_lead", "gap", "accel", "force", "collision")


def make_log_rows(
    n: int = 51, dt: float = 0.1, v: float = 20.0, gap: float = 50.0
) -> list[dict[str, object]]:
    """Rows of a steady run: host and lead at v [m/s], constant gap [m]."""
    return [
        {
            "t": round(i * dt, 6),
            "frame": i,
            "v_host": v,
            "v_lead": v,
            "gap": gap,
            "accel": 0.0,
            "force": 0.0,
            "collision": 0,
        }
        for i in range(n)
    ]
