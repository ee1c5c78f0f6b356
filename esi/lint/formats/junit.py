"""JUnit XML for GitLab and Jenkins: a test case per file, or per device in a file with several.

In a file with several devices each device is a test case and findings outside any device
(the Vendor, Groups, module libraries, schema errors there) go to one more test case named
after the file.  Error findings make a case fail; warnings and infos go to its system-out.
"""

from __future__ import annotations

from typing import TextIO

from lxml import etree

from ecatcfg.errors import location
from ecatcfg.esi.lint.finding import FileResult, Finding
from ecatcfg.esi.lint.rules import Rule


def test_cases(result: FileResult) -> list[tuple[str, list[Finding]]]:
    """(case name, its findings) for one file."""
    if len(result.devices) < 2:
        return [(result.file, list(result.findings))]
    cases: list[tuple[str, list[Finding]]] = []
    for dev in result.devices:
        name = f"{dev.type} {dev.selector} (line {dev.line})"
        cases.append((name, [f for f in result.findings if f.device == dev]))
    cases.append((f"{result.file} (outside devices)",
                  [f for f in result.findings if f.device is None]))
    return cases


def write(results: list[FileResult], rules: dict[str, Rule], out: TextIO,
          tool: str = "ecatcfg lint") -> None:
    suites = etree.Element("testsuites", name=tool)
    total = failed = 0
    for result in results:
        cases = test_cases(result)
        suite = etree.SubElement(suites, "testsuite", name=result.file,
                                 tests=str(len(cases)), time=f"{result.seconds:.3f}")
        suite_failures = 0
        for name, findings in cases:
            case = etree.SubElement(suite, "testcase", classname=result.file, name=name)
            errors = [f for f in findings if f.severity == "error"]
            others = [f for f in findings if f.severity != "error"]
            if errors:
                suite_failures += 1
                fail = etree.SubElement(case, "failure", type="lint",
                                        message=f"{len(errors)} error(s): {errors[0].rule} "
                                                f"{errors[0].message}")
                fail.text = "\n".join(_line(f) for f in errors)
            if others:
                etree.SubElement(case, "system-out").text = "\n".join(_line(f) for f in others)
        suite.set("failures", str(suite_failures))
        suite.set("errors", "0")
        total += len(cases)
        failed += suite_failures
    suites.set("tests", str(total))
    suites.set("failures", str(failed))
    suites.set("errors", "0")
    out.write(etree.tostring(suites, xml_declaration=True, encoding="UTF-8",
                             pretty_print=True).decode())


def _line(f: Finding) -> str:
    return f"{location(f.file, f.line, f.column)}: {f.severity} {f.rule} {f.message}"
