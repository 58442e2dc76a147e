"""Scoring a run log segment by segment gives the figures of scoring it whole."""

from __future__ import annotations

import json
from pathlib import Path

from energy_stream_logs import varied_logs, write_csv

from energy import evaluate_run

FROZEN = Path(__file__).parent / "data" / "evaluate_run_frozen.json"
"""evaluate_run's figures of :func:`varied_logs` as scored before streaming (the whole log at
once); re-record (``python tests/energy/test_streaming_metrics.py``) only for a deliberate
change of a figure."""
CASES = [(veh, settle) for veh in ("corolla", "leaf") for settle in (0.0, 15.0)] + [("average", 15.0)]


def _score_all(tmp: Path) -> dict[str, dict[str, object]]:
    out = {}
    for name, cols in varied_logs().items():
        path = write_csv(tmp / f"{name}.csv", cols)
        for veh, settle in CASES:
            out[f"{name}/{veh}/settle{settle:g}"] = evaluate_run(path, veh, settle_s=settle)
    return out


def test_a_one_segment_log_scores_exactly_as_before(tmp_path: Path) -> None:
    frozen = json.loads(FROZEN.read_text())
    got = _score_all(tmp_path)
    assert got.keys() == frozen.keys()
    for case, metrics in got.items():
        assert list(metrics) == list(frozen[case]), case
        for key, value in metrics.items():
            want = frozen[case][key]
            assert isinstance(value, float) == isinstance(want, float), (case, key)  # an int stays an int
            assert value == want, (case, key, value, want)


if __name__ == "__main__":  # re-record the frozen figures
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        FROZEN.write_text(json.dumps(_score_all(Path(d)), indent=1) + "\n")

