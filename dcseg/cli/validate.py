"""``dcseg validate``: check a capture and its masks; print a summary or every problem."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from dcseg.cli._options import add_flags, add_groups, build, capture_options, given


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "validate",
        help="check a capture and its masks",
        description="Check a capture (folder or .zip/.tar) and its masks. Prints a summary (with "
        "the mask format detected per folder) and exits 0, or lists every problem found (file "
        "and reason) and exits 1.",
    )
    parser.add_argument("capture", type=Path, help="capture folder or archive")
    parser.add_argument(
        "--agnostic-masks",
        type=Path,
        help="class-agnostic masks: a folder, or a COCO JSON (formats: docs/masks.md)",
    )
    parser.add_argument(
        "--semantic-masks",
        type=Path,
        help="class-aware class maps: a folder, or a COCO panoptic JSON (docs/masks.md)",
    )
    parser.add_argument("--vocabulary", type=Path, help="class names (.txt or .json)")
    parser.add_argument("--gt", type=Path, help="ground-truth PLY (x y z label [instance])")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    add_groups(parser, "capture")
    add_flags(parser.add_argument_group("class maps"), "segment", only=("unlabelled_id",))
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dcseg.inputs import RunInputs
    from dcseg.io.validate import validate_inputs

    if args.semantic_masks is not None and args.vocabulary is None:
        sys.stderr.write("dcseg validate: --semantic-masks needs --vocabulary\n")
        return 2
    paths = RunInputs(
        capture=args.capture,
        agnostic_masks=args.agnostic_masks,
        semantic_masks=args.semantic_masks,
        vocabulary=args.vocabulary,
        ground_truth=args.gt,
    )
    unlabelled = build("fast", {"segment": given(args, "segment")}).pipeline.assign.unlabelled_id
    report = validate_inputs(paths, capture_options(args), unlabelled=unlabelled)
    if args.json:
        problems = [{"path": p.path, "reason": p.reason} for p in report.problems]
        out = {"ok": report.ok, "summary": report.summary, "problems": problems}
        sys.stdout.write(json.dumps(out, indent=2) + "\n")
    else:
        sys.stdout.write(format_report(report.summary, [str(p) for p in report.problems]))
    return 0 if report.ok else 1


def format_report(summary: dict[str, Any], problems: list[str]) -> str:
    """The human-readable report: one section per input, then the problems."""
    lines: list[str] = []
    for section, values in summary.items():
        if values is None:
            continue
        lines.append(f"{section}:")
        lines.extend(f"  {key}: {_show(value)}" for key, value in values.items())
    if problems:
        lines.append(f"{len(problems)} problem(s):")
        lines.extend(f"  - {p}" for p in problems)
    else:
        lines.append("OK: no problems found")
    return "\n".join(lines) + "\n"


def _show(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return ", ".join(str(v) for v in value) if value else "(none)"
    return str(value)
