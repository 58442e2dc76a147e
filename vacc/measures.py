"""The names of the figures a gate report measures beside its checks (``measures``): written
by :mod:`vacc.gates`, read by :mod:`vacc.seeds_cmd`. Apart, so that `vacc seeds` imports
neither torch nor the simulator."""

from __future__ import annotations

__all__ = ["MEAN_GAP_RMSE", "ISO_JERK_SHARE", "ENERGY_RATIO", "CLOSEST_GAP"]

MEAN_GAP_RMSE = "mean gap RMSE (m)"
ISO_JERK_SHARE = "mean ISO jerk share"
ENERGY_RATIO = "energy / the ACC's"
CLOSEST_GAP = "closest gap (m)"
