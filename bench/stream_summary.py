"""``bench.stream``'s runs over many cameras and sizes (issue 37) summed up: per transport the mean of
each figure and the worst case beside it, and for each video codec how it compares with the tiles
of the same run (same size, same camera path).

* ``psnr_mean`` … (every number a run has): the mean over the runs; ``runs``: how many streamed;
* ``psnr_worst``: the lowest of the runs' ``psnr_mean`` (dB), ``psnr_worst_run`` which run;
* ``vs_tiles_db_mean``, ``vs_tiles_db_worst``: the codec's ``psnr_mean`` minus the tiles' in the same
  run (dB; worst: the lowest), with ``vs_tiles_db_worst_run``;
* ``wire_ratio_mean``, ``wire_ratio_worst``: the codec's bytes a frame on the wire over the tiles' in
  the same run (worst: the highest), with ``wire_ratio_worst_run``; ``message_ratio_*``: the same of
  the messages' bytes, before permessage-deflate.
"""

from __future__ import annotations

import statistics
from typing import Any

TILES = "tiles"


def _name(run: dict[str, Any]) -> str:
    return f"{run['size'][0]}x{run['size'][1]} {run['camera']}"


def _mean_and_worst(values: list[tuple[float, str]], prefix: str, lowest: bool) -> dict[str, Any]:
    """``{prefix}_mean``, ``{prefix}_worst`` (the lowest, or the highest) and ``{prefix}_worst_run``
    of (value, run name) pairs."""
    if not values:
        return {}
    worst = (min if lowest else max)(values, key=lambda pair: pair[0])
    return {f"{prefix}_mean": round(statistics.fmean(v for v, _ in values), 3), f"{prefix}_worst": round(worst[0], 3),
            f"{prefix}_worst_run": worst[1]}


def summarize(runs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per transport, over ``runs`` (each ``{"size", "camera", "transports": {transport: figures}}``):
    the figures described in the module docstring."""
    out: dict[str, dict[str, Any]] = {}
    transports = dict.fromkeys(t for run in runs for t in run["transports"])
    for transport in transports:
        streamed = [(run, run["transports"][transport]) for run in runs
                    if "fps" in run["transports"].get(transport, {})]
        if not streamed:
            continue
        numbers = dict.fromkeys(k for _, row in streamed for k, v in row.items()
                                if isinstance(v, int | float) and not isinstance(v, bool))
        summary: dict[str, Any] = {"runs": len(streamed)}
        for key in numbers:
            values = [row[key] for _, row in streamed if isinstance(row.get(key), int | float)]
            summary[key] = round(statistics.fmean(values), 3) if values else None
        summary.update(_mean_and_worst([(row["psnr_mean"], _name(run)) for run, row in streamed
                                        if row.get("psnr_mean") is not None], "psnr", lowest=True))
        if transport != TILES:
            paired = [(run, row, run["transports"][TILES]) for run, row in streamed
                      if "fps" in run["transports"].get(TILES, {})]
            summary.update(_mean_and_worst([(row["psnr_mean"] - tiles["psnr_mean"], _name(run))
                                            for run, row, tiles in paired
                                            if row.get("psnr_mean") is not None and tiles.get("psnr_mean") is not None],
                                           "vs_tiles_db", lowest=True))
            summary.update(_mean_and_worst([(row["wire_bytes_per_frame"] / tiles["wire_bytes_per_frame"], _name(run))
                                            for run, row, tiles in paired if tiles["wire_bytes_per_frame"]],
                                           "wire_ratio", lowest=False))
            summary.update(_mean_and_worst([(row["bytes_per_frame"] / tiles["bytes_per_frame"], _name(run))
                                            for run, row, tiles in paired if tiles["bytes_per_frame"]],
                                           "message_ratio", lowest=False))
        out[transport] = summary
    return out


def cell(value: float | None, width: int, places: int) -> str:
    """``value`` right-aligned in ``width`` with ``places`` decimals; '-' for None."""
    return f"{'-':>{width}}" if value is None else f"{value:>{width}.{places}f}"


def summary_table(by_size: dict[str, dict[str, dict[str, Any]]]) -> list[str]:
    """The summary's lines: per size and transport, means and worst cases (the worst run named)."""
    lines = ["Over the runs, mean / worst (worst: lowest PSNR and PSNR against the tiles, highest byte ratio):",
             f"{'size':<10}{'transport':<10}{'runs':>5}{'PSNR':>15}{'vs tiles dB':>15}{'wire KB':>9}"
             f"{'wire / tiles':>15}{'msgs / tiles':>15}{'fps':>6}{'crf':>7}  worst run (vs tiles)"]
    for size, summary in by_size.items():
        for transport, row in summary.items():
            lines.append(
                f"{size:<10}{transport:<10}{row['runs']:>5}{cell(row.get('psnr_mean'), 7, 2)} /"
                f"{cell(row.get('psnr_worst'), 6, 2)}{cell(row.get('vs_tiles_db_mean'), 7, 2)} /"
                f"{cell(row.get('vs_tiles_db_worst'), 6, 2)}{cell((row.get('wire_bytes_per_frame') or 0) / 1000, 9, 1)}"
                f"{cell(row.get('wire_ratio_mean'), 7, 3)} /{cell(row.get('wire_ratio_worst'), 6, 3)}"
                f"{cell(row.get('message_ratio_mean'), 7, 3)} /{cell(row.get('message_ratio_worst'), 6, 3)}"
                f"{cell(row.get('fps'), 6, 1)}{cell(row.get('crf'), 7, 2)}  {row.get('vs_tiles_db_worst_run', '')}")
    return lines
