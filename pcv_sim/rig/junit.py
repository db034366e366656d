"""Scenario results as JUnit XML, as Jenkins, GitLab and GitHub read it: one `testsuite`, one
`testcase` per scenario (a `failure` when an assertion failed or the run stopped, an `error`
for a file that cannot be run), each assertion a `property` of its case (value, limit, margin
and worst time, SI) and in the case's `system-out`."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["junit_xml", "write_junit"]


def _num(x: Any) -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.6g}"


def junit_xml(results: Sequence[Mapping[str, Any]], *, suite: str = "pcv_sim scenarios") -> str:
    """`results` as the scenario command makes them (`status` 0 passed, 1 failed, 2 a bad file)."""
    root = ET.Element("testsuites")
    ts = ET.SubElement(root, "testsuite", name=suite, tests=str(len(results)),
                       failures=str(sum(r["status"] == 1 for r in results)),
                       errors=str(sum(r["status"] == 2 for r in results)), skipped="0",
                       time=f"{sum(float(r.get('wall_time_s') or 0.0) for r in results):.3f}")
    for r in results:
        case = ET.SubElement(ts, "testcase", classname="scenario", name=str(r["name"]),
                             file=str(r.get("path", "")), time=f"{float(r.get('wall_time_s') or 0.0):.3f}")
        assertions = r.get("assertions", [])
        if assertions:
            props = ET.SubElement(case, "properties")
            for a in assertions:
                ET.SubElement(props, "property", name=f"assertion: {a['name']}",
                              value=f"{'pass' if a['passed'] else 'FAIL'}; value {_num(a.get('value'))}, limit "
                                    f"{_num(a.get('limit'))}, margin {_num(a.get('margin'))}, worst at "
                                    f"{_num(a.get('time'))} s")
        lines = [f"{'ok  ' if a['passed'] else 'FAIL'} {a['name']}: {a['detail']}" for a in assertions]
        lines += [f"note: {n}" for n in r.get("notes", [])]
        if r["status"] == 2:
            ET.SubElement(case, "error", message=str(r.get("error", "")), type="ScenarioError").text = r.get("error")
        elif r["status"] == 1:
            failed = [a["name"] for a in assertions if not a["passed"]]
            msg = r.get("error") or f"failed: {', '.join(failed)}"
            ET.SubElement(case, "failure", message=msg, type="AssertionError").text = "\n".join(
                [msg, *[line for line in lines if line.startswith("FAIL")]])
        if lines:
            ET.SubElement(case, "system-out").text = "\n".join(lines)
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_junit(results: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(junit_xml(results), encoding="utf-8")
    return p
