"""OUT/batch.csv and OUT/index.html: one row per input, rewritten atomically as runs finish."""

from __future__ import annotations

import csv
import html
import io
from pathlib import Path

from ..io.atomic import write_text
from .task import record_fields

# index.html's columns: (record field, heading); the links to each run's pages follow them.
HTML_COLUMNS = (("name", "run"), ("status", "status"), ("frames", "frames"), ("valid_frames", "valid"),
                ("wall_seconds", "wall s"), ("physics", "physics"), ("reprojection_error_px", "reproj. px"),
                ("skate_percent", "skate %"), ("penetration_percent", "penetration %"),
                ("floating_percent", "floating %"), ("mean_acceleration", "jitter m/s²"),
                ("residual_force_percent_bw", "residual % BW"), ("com_over_support_percent", "CoM over support %"),
                ("fps_by_jumps", "fps its jumps say"), ("reason", "reason"))


def write_tables(out_dir: Path, records: list[dict]) -> None:
    """batch.csv (every field of every record) and index.html (the figures, with relative links to each finished
    run's report.html and viewer.html) in `out_dir`."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=record_fields(), lineterminator="\n")
    writer.writeheader()
    writer.writerows(records)
    write_text(out_dir / "batch.csv", buffer.getvalue())
    write_text(out_dir / "index.html", index_html(out_dir, records))


def index_html(out_dir: Path, records: list[dict]) -> str:
    counts = {status: sum(r["status"] == status for r in records) for status in ("done", "failed", "pending")}
    heading = "".join(f"<th>{html.escape(title)}</th>" for _, title in HTML_COLUMNS) + "<th>pages</th>"
    rows = []
    for record in records:
        cells = "".join(f"<td>{html.escape(str(record[field]))}</td>" for field, _ in HTML_COLUMNS)
        links = " ".join(f'<a href="{html.escape(record["name"])}/{page}.html">{page}</a>'
                         for page in ("report", "viewer")
                         if record["status"] == "done" and (out_dir / record["name"] / f"{page}.html").is_file())
        rows.append(f'<tr class="{html.escape(record["status"])}" title="{html.escape(record["input"])}">'
                    f"{cells}<td>{links}</td></tr>")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>physmocap batch: {html.escape(out_dir.name)}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; font-size: 0.9em; }}
th, td {{ border-bottom: 1px solid #ddd; padding: 0.25em 0.6em; text-align: left; }}
tr.failed td {{ background: #fdecea; }} tr.pending td {{ color: #888; }}
</style></head><body>
<h1>physmocap batch</h1>
<p>{len(records)} inputs: {counts["done"]} done, {counts["failed"]} failed, {counts["pending"]} pending.
Every figure is of the final motion (see each run's report for their meaning); batch.csv holds them all.</p>
<table><thead><tr>{heading}</tr></thead><tbody>
{chr(10).join(rows)}
</tbody></table></body></html>
"""
