"""Accuracy checks for continuous integration: an experiment's ``[checks]`` thresholds against its summary.

A config may carry thresholds on summary figures (columns of
:func:`ptm_bench.reporting.summary.aggregate`, listed in
``ptm_bench.evaluation.experiment.CHECK_METRICS``), for one variant or for
every model variant::

    [checks]
    ece = "<= 0.05"                                   # every model variant
    "odometry+appearance".gt_mass = ">= 0.9"          # one variant (gt_mass_mean is the same figure)

A check holds when it holds in every world x aliasing x noise condition of
its variant; a variant without finished cells fails it. ``ptm-bench run
--check`` prints :func:`check_table`, writes :func:`junit_xml` (one test case
per check and condition, which CI systems display) and exits non-zero when a
check fails.

    >>> import pandas as pd
    >>> summary = pd.DataFrame({"world": ["office"], "aliasing": [0.0], "noise": [1.0], "variant": ["v"],
    ...                         "gt_mass": [0.93]})
    >>> check = {"variant": "v", "metric": "gt_mass", "operator": ">=", "threshold": 0.9, "condition": ">= 0.9"}
    >>> evaluate_checks([check], summary)[["variant", "metric", "condition", "value", "held"]].to_dict("records")
    [{'variant': 'v', 'metric': 'gt_mass', 'condition': '>= 0.9', 'value': 0.93, 'held': True}]
"""

from __future__ import annotations

import math
import operator
import xml.etree.ElementTree as ElementTree

import pandas as pd

__all__ = ["check_table", "evaluate_checks", "junit_xml"]

_OPERATORS = {">=": operator.ge, "<=": operator.le, ">": operator.gt, "<": operator.lt, "==": operator.eq}
_CONDITION = ["world", "aliasing", "noise"]


def evaluate_checks(checks, summary: pd.DataFrame) -> pd.DataFrame:
    """One row per check and condition: variant, world, aliasing, noise, metric, condition, value, held."""
    rows = []
    for check in checks:
        group = summary[summary["variant"] == check["variant"]] if len(summary) else summary
        if not len(group):
            rows.append({"variant": check["variant"], "world": "", "aliasing": math.nan, "noise": math.nan,
                         "metric": check["metric"], "condition": check["condition"], "value": math.nan, "held": False,
                         "note": "no finished cells"})
            continue
        for _, row in group.iterrows():
            value = float(row[check["metric"]]) if check["metric"] in row else math.nan
            held = not math.isnan(value) and bool(_OPERATORS[check["operator"]](value, check["threshold"]))
            rows.append({"variant": check["variant"], **{key: row[key] for key in _CONDITION},
                         "metric": check["metric"], "condition": check["condition"], "value": value, "held": held,
                         "note": "" if not math.isnan(value) else "no value"})
    return pd.DataFrame(rows, columns=["variant", *_CONDITION, "metric", "condition", "value", "held", "note"])


def check_table(results: pd.DataFrame) -> str:
    """The results as aligned text, failures marked."""
    lines = [f"{'':5}{'variant':<24}{'world':<14}{'aliasing':>9}{'noise':>7}  {'metric':<18}{'condition':<12}{'value':>10}"]
    for _, row in results.iterrows():
        mark = "ok" if row["held"] else "FAIL"
        value = f"{row['value']:.4g}" if row["value"] == row["value"] else row["note"]
        lines.append(f"{mark:<5}{row['variant']:<24}{str(row['world']):<14}{row['aliasing']:>9.3g}{row['noise']:>7.3g}  "
                     f"{row['metric']:<18}{row['condition']:<12}{value:>10}")
    return "\n".join(lines)


def junit_xml(results: pd.DataFrame, suite: str) -> str:
    """A JUnit XML report: one ``testcase`` per check and condition, a ``failure`` for each that did not hold."""
    failures = int((~results["held"]).sum())
    root = ElementTree.Element("testsuites", tests=str(len(results)), failures=str(failures))
    element = ElementTree.SubElement(root, "testsuite", name=suite, tests=str(len(results)), failures=str(failures),
                                     errors="0", skipped="0")
    for _, row in results.iterrows():
        where = f"{row['world']} a={row['aliasing']:g} noise={row['noise']:g}"
        case = ElementTree.SubElement(element, "testcase", classname=f"{suite}.{row['variant']}",
                                      name=f"{row['metric']} {row['condition']} [{where}]")
        if not row["held"]:
            shown = f"{row['value']:.6g}" if row["value"] == row["value"] else row["note"]
            ElementTree.SubElement(case, "failure", message=f"{row['metric']} = {shown}, expected {row['condition']}")
    return ElementTree.tostring(root, encoding="unicode", xml_declaration=True) + "\n"
