"""``ecatcfg report``: the HTML page of an ENI, opened in a real browser.

Debian's Chromium renders the page headless (``--screenshot``: a PNG), and, driven through
the DevTools protocol by playwright (with that same Chromium, no browser download), the
tests read the DOM it built: no console errors, no request but the file itself, every slave
and every variable of the ENI present, and the topology's links drawn from the parent's box
to the child's.  What is expected is read from the ENI with plain lxml (the ENI reader is
code under test).  Chromium missing: skipped locally, a failure in CI
(``ECATCFG_REQUIRE_TOOLS``, ``prereq.py``).
"""

from __future__ import annotations

import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path
from typing import Any

import prereq
import pytest
from conftest import EXAMPLES, ROOT, corpus_eni
from lxml import etree, html

from ecatcfg.eni import report
from ecatcfg.eni.reader import read_file
from ecatcfg.esi.lint.finding import DeviceRef, Finding

# Chromium as root needs --no-sandbox; the rest keeps it from talking to anything.
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync"]
CORPUS_ENIS = ["corpus/jn-ec-master/mega_master_eni.xml",     # TwinCAT-style, frame image
               "corpus/acontis-doc/acontis-TrainingSlaves-ENI.xml",   # EC-Engineer
               "corpus/rocos-ethercat/eni_tech6.xml",                 # 6 drives
               "corpus-extra/hydra/hydra_wholebody_20160108_DC.xml",  # 16 slaves, 2 MB page
               "corpus-extra/pmec-wec-bench/DriveAndDUTAndPAAndLoadXML.xml"]  # 20, couplers


def chromium_path() -> str:
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        prereq.missing("chromium", "no chromium on PATH (Debian: apt-get install chromium)",
                       prereq.TOOLS)
    return path


@pytest.fixture(scope="module")
def browser() -> Any:
    from playwright.sync_api import sync_playwright
    path = chromium_path()
    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=path, args=CHROMIUM_ARGS)
        yield chromium
        chromium.close()


class Opened:
    """A page loaded in Chromium with what it logged and requested."""

    def __init__(self, browser: Any, page_file: Path) -> None:
        self.page = browser.new_page()
        self.console: list[tuple[str, str]] = []
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: self.console.append((m.type, m.text)))
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.url = page_file.resolve().as_uri()
        self.page.goto(self.url, wait_until="load")

    def texts(self, selector: str) -> list[str]:
        return self.page.eval_on_selector_all(selector, "els => els.map(e => e.textContent)")

    def clean(self) -> None:
        assert [m for m in self.console if m[0] in ("error", "warning")] == []
        assert self.errors == []
        assert self.requests == [self.url]          # nothing fetched: self-contained


def write_report(eni: Path, out: Path, *more: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "report", str(eni), "-o",
                           str(out), "--no-cache", *more], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)


def xml_names(eni: Path) -> tuple[list[str], list[str]]:
    """(slave names in file order, variable names: inputs then outputs), by lxml."""
    root = etree.parse(str(eni)).getroot()
    slaves = [s.findtext("Info/Name") for s in root.findall("Config/Slave")]
    variables = [v.findtext("Name") for part in ("Inputs", "Outputs")
                 for v in root.findall(f"Config/ProcessImage/{part}/Variable")]
    return slaves, variables


def compiled_tree(tmp_path: Path) -> Path:
    eni = tmp_path / "tree.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile",
                           str(EXAMPLES / "tree" / "tree.yaml"), "--esi",
                           str(EXAMPLES / "tree" / "esi"), "--esi", str(EXAMPLES / "esi"),
                           "-o", str(eni), "--no-cache"], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    return eni


def expected_links(eni: Path) -> set[tuple[str, str, str]]:
    """(parent, child, port) from each slave's PreviousPort (the Selected one, else the
    first), read with lxml; the first slave is behind the master."""
    slaves = etree.parse(str(eni)).getroot().findall("Config/Slave")
    by_addr = {s.findtext("Info/PhysAddr"): s.findtext("Info/Name") for s in slaves}
    links = set()
    for s in slaves:
        ports = s.findall("PreviousPort")
        chosen = next((p for p in ports if p.get("Selected") in ("1", "true")),
                      ports[0] if ports else None)
        if chosen is not None:
            links.add((by_addr[chosen.findtext("PhysAddr")], s.findtext("Info/Name"),
                       chosen.findtext("Port")))
    return links


# Each link in the SVG, with the parent's and child's names and boxes and the path's two
# ends, all in screen coordinates as Chromium laid them out.
_LINKS_JS = """svg => Array.from(svg.querySelectorAll('g.link-group')).map(g => {
  const node = i => i === '-1' ? svg.querySelector('g[data-node="master"]')
                               : svg.querySelector(`g.node[data-slave="${i}"]`);
  const box = n => { const r = n.querySelector('rect').getBoundingClientRect();
                     return [r.left, r.top, r.right, r.bottom]; };
  const path = g.querySelector('path'), m = path.getScreenCTM();
  const at = l => { const p = path.getPointAtLength(l).matrixTransform(m); return [p.x, p.y]; };
  const parent = node(g.dataset.parent), child = node(g.dataset.child);
  return {parent: parent.querySelector('text.name').textContent,
          child: child.querySelector('text.name').textContent,
          port: g.dataset.port, parentBox: box(parent), childBox: box(child),
          start: at(0), end: at(path.getTotalLength())};
})"""


def _on_edge(point: list[float], box: list[float]) -> bool:
    """On the box's outline (1.5 px of anti-aliasing slack)."""
    x, y = point
    left, top, right, bottom = box
    inside = left - 1.5 <= x <= right + 1.5 and top - 1.5 <= y <= bottom + 1.5
    edge = min(abs(x - left), abs(x - right), abs(y - top), abs(y - bottom)) <= 1.5
    return inside and edge


def xml_ebus_links(eni: Path) -> set[tuple[str, str, str]]:
    """The links of :func:`expected_links` on the parent's E-bus: the port's letter in the
    parent's ``Info/Physics`` (ETG.2100: one letter per port A-D) is ``K``."""
    slaves = etree.parse(str(eni)).getroot().findall("Config/Slave")
    physics = {s.findtext("Info/Name"): s.findtext("Info/Physics") or "" for s in slaves}
    return {(parent, child, port) for parent, child, port in expected_links(eni)
            if "ABCD".index(port) < len(physics[parent])
            and physics[parent]["ABCD".index(port)] == "K"}


def check_rails(links: list[dict[str, Any]], ebus: set[tuple[str, str, str]]) -> None:
    """E-bus neighbours side by side (the child right of the parent on the same row, or
    on a row below when the rail wraps); what leaves over Ethernet is below its parent."""
    for x in links:
        parent, child = x["parentBox"], x["childBox"]
        if (x["parent"], x["child"], x["port"]) in ebus:
            beside = abs(child[1] - parent[1]) < 1 and child[0] >= parent[2]
            wrapped = child[1] >= parent[3]
            assert beside or wrapped, x
        else:
            assert child[1] >= parent[3], x


def drawn_links(opened: Opened) -> list[dict[str, Any]]:
    return opened.page.eval_on_selector("#topology-svg", _LINKS_JS)


def check_drawing(opened: Opened, names: list[str]) -> None:
    links = drawn_links(opened)
    for link in links:
        assert _on_edge(link["start"], link["parentBox"]), link
        assert _on_edge(link["end"], link["childBox"]), link
    boxes = opened.page.eval_on_selector_all(
        "#topology-svg rect", "rs => rs.map(r => { const b = r.getBoundingClientRect(); "
        "return [b.left, b.top, b.right, b.bottom]; })")
    assert len(boxes) == len(names) + 1                        # and the master's
    for i, a in enumerate(boxes):                               # no two boxes overlap
        for b in boxes[i + 1:]:
            assert a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1], (a, b)


# Each bit cell of the process-image map: direction, byte, bit, the slave it is coloured
# for (its name, from that slave's table) and whether its colour is that slave's swatch.
_CELLS_JS = """tables => tables.flatMap(t => Array.from(t.querySelectorAll('tr[data-byte]'))
  .flatMap(tr => Array.from(tr.querySelectorAll('td.bit')).map((td, bit) => {
    const id = td.dataset.slave;
    const card = id === undefined ? null : document.getElementById('slave-' + id);
    const swatch = card && getComputedStyle(card.querySelector('.swatch')).backgroundColor;
    return [t.dataset.direction, +tr.dataset.byte, bit,
            card && card.querySelector('.slave-name').textContent,
            card ? getComputedStyle(td).backgroundColor === swatch : null];
  })))"""


def xml_owners(eni: Path) -> dict[tuple[str, int], str]:
    """(direction, bit) -> slave name, from each slave's ProcessData Send (outputs) and
    Recv (inputs) BitStart/BitLength, by lxml; the first slave listed wins an overlap."""
    owners: dict[tuple[str, int], str] = {}
    for slave in etree.parse(str(eni)).getroot().findall("Config/Slave"):
        for tag, direction in (("Send", "out"), ("Recv", "in")):
            for r in slave.findall(f"ProcessData/{tag}"):
                start, length = int(r.findtext("BitStart")), int(r.findtext("BitLength"))
                for bit in range(start, start + length):
                    owners.setdefault((direction, bit), slave.findtext("Info/Name"))
    return owners


def check_image_map(opened: Opened, eni: Path) -> None:
    cells = opened.page.eval_on_selector_all("table.map", _CELLS_JS)
    owners = xml_owners(eni)
    shown = {(d, byte * 8 + bit): name for d, byte, bit, name, _ in cells}
    assert all(same for *_, same in cells if same is not None)   # coloured as its slave
    assert {k: v for k, v in shown.items() if v is not None} == owners


@pytest.mark.parametrize("name", CORPUS_ENIS)
def test_corpus_eni_in_chromium(request, browser, tmp_path, name):
    eni = corpus_eni(request, name)
    out = tmp_path / "network.html"
    done = write_report(eni, out)
    assert done.returncode == 0, done.stderr
    slaves, variables = xml_names(eni)
    assert slaves and variables
    opened = Opened(browser, out)
    opened.clean()
    assert opened.texts("section.slave .slave-name") == slaves
    assert sorted(opened.texts("#topology-svg g.node[data-slave] text.name")) == sorted(slaves)
    assert opened.texts("table.variables .variable-name") == variables
    assert sorted(opened.texts("table.map .var")) == sorted(variables)
    check_drawing(opened, slaves)
    drawn = {(x["parent"], x["child"], x["port"]) for x in drawn_links(opened)}
    assert expected_links(eni) <= drawn
    # Expected working counters of the cyclic commands, as the file gives them.
    root = etree.parse(str(eni)).getroot()
    cnts = [c.findtext("Cnt") or "-" for c in root.findall("Config/Cyclic/Frame/Cmd")]
    assert opened.texts("table.frame td.wkc") == cnts
    check_image_map(opened, eni)
    opened.page.close()


def test_tree_with_a_junction_shows_its_branches(browser, tmp_path):
    eni = compiled_tree(tmp_path)
    out = tmp_path / "tree.html"
    assert write_report(eni, out).returncode == 0
    slaves, variables = xml_names(eni)
    opened = Opened(browser, out)
    opened.clean()
    assert opened.texts("section.slave .slave-name") == slaves
    assert opened.texts("table.variables .variable-name") == variables
    check_drawing(opened, slaves)
    check_image_map(opened, eni)
    links = drawn_links(opened)
    drawn = {(x["parent"], x["child"], x["port"]) for x in links}
    expected = expected_links(eni)
    assert drawn == expected | {("example-tree", slaves[0], "")}
    # The junction's three ports each lead on: its E-bus port (a K in its Physics, read by
    # lxml) to the terminal beside it on the rail, its Ethernet ports to branches below.
    from_junction = [x for x in links if x["parent"] == "junction"]
    assert sorted(x["port"] for x in from_junction) == sorted(
        p for parent, _, p in expected if parent == "junction") == ["B", "C", "D"]
    ebus = xml_ebus_links(eni)
    assert ("junction", "outputs", "C") in ebus and ("junction", "axis1", "D") not in ebus
    check_rails(links, ebus)
    rail = [x for x in links if (x["parent"], x["child"], x["port"]) in ebus]
    assert len(rail) == 3 and all(abs(x["childBox"][1] - x["parentBox"][1]) < 1 for x in rail)
    # The port letters are drawn as text in the SVG.
    assert sorted(opened.texts("#topology-svg text.port")) == sorted(p for *_, p in expected)
    # Hovering a slave's box marks its bits in the map (the page's script), and only its.
    axis2 = slaves.index("axis2")
    opened.page.hover(f'#topology-svg g.node[data-slave="{axis2}"] rect')
    marked = opened.page.eval_on_selector_all(
        "td.bit.hl", "tds => tds.map(td => td.dataset.slave)")
    assert marked and set(marked) == {str(axis2)}
    assert len(marked) == len(opened.page.query_selector_all(f'td.bit[data-slave="{axis2}"]'))
    opened.page.close()


def _passive_terminal(name: str, previous: str) -> etree._Element:
    """A passive terminal as TwinCAT writes one: no PhysAddr, empty ProcessData."""
    slave = etree.fromstring(
        "<Slave><Info><Name/><VendorId>2</VendorId><ProductCode>0</ProductCode>"
        f"<RevisionNo>0</RevisionNo><SerialNo>0</SerialNo></Info><ProcessData/>"
        f'<PreviousPort Selected="true"><Port>B</Port><PhysAddr>{previous}</PhysAddr>'
        "</PreviousPort></Slave>")
    slave.find("Info/Name").text = name               # escaped by lxml as it is written
    return slave


def test_passive_terminal_is_marked_and_passes_the_line_on(browser, tmp_path):
    """A passive terminal after 'inputs' (on its port B, where the junction is too): drawn
    dashed, and the junction behind it; a name with markup stays text."""
    tree = etree.parse(str(compiled_tree(tmp_path)))
    inputs = next(s for s in tree.getroot().findall("Config/Slave")
                  if s.findtext("Info/Name") == "inputs")
    odd = 'feed <b>&"amp"</b><script>alert(1)</script>'
    inputs.addnext(_passive_terminal(odd, inputs.findtext("Info/PhysAddr")))
    eni = tmp_path / "passive.eni.xml"
    tree.write(str(eni), xml_declaration=True, encoding="UTF-8")
    out = tmp_path / "passive.html"
    assert write_report(eni, out).returncode == 0
    opened = Opened(browser, out)
    opened.clean()                                  # the script in the name did not run
    assert odd in opened.texts("section.slave .slave-name")
    dashed = opened.page.eval_on_selector_all(
        "#topology-svg g.node[data-passive] rect",
        "rs => rs.map(r => getComputedStyle(r).strokeDasharray)")
    assert len(dashed) == 1 and dashed[0] not in ("none", "")
    links = {(x["parent"], x["child"], x["port"]) for x in drawn_links(opened)}
    assert ("inputs", odd, "B") in links and (odd, "junction", "") in links
    check_drawing(opened, xml_names(eni)[0])
    opened.page.close()


def _png_size_and_colours(data: bytes) -> tuple[tuple[int, int], int]:
    """(width, height) from IHDR and the number of distinct byte values of the pixel data
    (a blank page has one or two)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    size = struct.unpack(">II", data[16:24])
    idat, pos = b"", 8
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if kind == b"IDAT":
            idat += data[pos + 8:pos + 8 + length]
        pos += 12 + length
    return size, len(set(zlib.decompress(idat)))


def test_chromium_renders_the_page_to_png(tmp_path):
    chromium = chromium_path()
    eni = compiled_tree(tmp_path)
    out = tmp_path / "tree.html"
    assert write_report(eni, out).returncode == 0
    png = tmp_path / "tree.png"
    done = subprocess.run([chromium, "--headless", *CHROMIUM_ARGS, "--window-size=900,1200",
                           f"--screenshot={png}", out.resolve().as_uri()],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    size, colours = _png_size_and_colours(png.read_bytes())
    assert size == (900, 1200) and colours > 50


# ----------------------------------------------------------------- findings, errors, output

def _finding(rule: str, severity: str, message: str, line: int) -> Finding:
    return Finding("x.eni.xml", line, None, rule, severity,  # type: ignore[arg-type]
                   message, DeviceRef(2, 3, 4, "axis1", 10))


def test_findings_have_their_own_section(tmp_path):
    plan = read_file(compiled_tree(tmp_path))
    findings = [_finding("ENI301", "error", "slave 'axis1': writes 0x1C12:00, read-only", 40),
                _finding("ENI102", "warning", "frame 0: 1500 bytes", 7)]
    page = html.fromstring(report.render(plan, "tree.eni.xml", findings))
    rows = page.xpath("//h2[@id='findings']/following-sibling::table[1]"
                      "//tr[@class='finding']")
    assert [[td.text_content() for td in r.findall("td")] for r in rows] == [
        ["warning", "ENI102", "7", "frame 0: 1500 bytes"],
        ["error", "ENI301", "40", "slave 'axis1': writes 0x1C12:00, read-only"]]
    none = html.fromstring(report.render(plan, "tree.eni.xml", None))
    assert none.get_element_by_id("not-checked") is not None
    assert not none.xpath("//tr[@class='finding']")
    clean = html.fromstring(report.render(plan, "tree.eni.xml", []))
    assert "found nothing" in clean.get_element_by_id("no-findings").text_content()


def test_findings_of_check_are_shown_as_check_gives_them(tmp_path):
    """The page takes ``check``'s own findings (``eni/check``): an expected working counter
    made wrong in the compiled tree is ENI104, and the page lists what check says."""
    from ecatcfg.eni.check import check_eni
    tree = etree.parse(str(compiled_tree(tmp_path)))
    lrw = next(c for c in tree.getroot().findall("Config/Cyclic/Frame/Cmd")
               if c.findtext("Cmd") == "12")
    lrw.find("Cnt").text = str(int(lrw.findtext("Cnt")) + 1)
    eni = tmp_path / "wkc.eni.xml"
    tree.write(str(eni), xml_declaration=True, encoding="UTF-8")
    findings = check_eni(eni, None, use_cache=False).findings
    assert [f.rule for f in findings] == ["ENI104"]
    page = html.fromstring(report.render(read_file(eni), str(eni), findings))
    rows = page.xpath("//tr[@class='finding']")
    assert [[td.text_content() for td in r.findall("td")] for r in rows] == [
        [f.severity, f.rule, str(f.line), f.message] for f in findings]


def test_a_bad_eni_names_file_and_line_and_writes_nothing(tmp_path):
    eni = compiled_tree(tmp_path)
    text = eni.read_text().splitlines()
    line = next(k for k, t in enumerate(text) if "<PhysAddr>" in t)
    text[line] = text[line].replace("<PhysAddr>", "<PhysAddr>x")
    bad = tmp_path / "bad.eni.xml"
    bad.write_text("\n".join(text) + "\n")
    out = tmp_path / "bad.html"
    done = write_report(bad, out)
    assert done.returncode == 1 and f"{bad}:{line + 1}" in done.stderr
    assert "Traceback" not in done.stderr and not out.exists()
    # Not an ENI, or the ENI itself as output: usage errors, nothing written.
    esi = EXAMPLES / "esi" / "ecatcfg-EXD402-drive.xml"
    assert write_report(esi, out).returncode == 2 and not out.exists()
    same = write_report(eni, eni)
    assert same.returncode == 2 and "would replace the ENI" in same.stderr


def test_the_command_shows_what_check_finds(tmp_path):
    """``ecatcfg report`` runs ``check`` (with ``--esi``, against the slaves' devices too):
    a wrong expected working counter is on the page as ENI104 at the Cnt's line, and
    ``--no-check`` says check was not run."""
    tree = etree.parse(str(compiled_tree(tmp_path)))
    lrw = next(c for c in tree.getroot().findall("Config/Cyclic/Frame/Cmd")
               if c.findtext("Cmd") == "12")
    lrw.find("Cnt").text = str(int(lrw.findtext("Cnt")) + 1)
    eni = tmp_path / "wkc.eni.xml"
    tree.write(str(eni), xml_declaration=True, encoding="UTF-8")
    cmd_line = etree.parse(str(eni)).getroot()
    cmd_line = next(c for c in cmd_line.findall("Config/Cyclic/Frame/Cmd")
                    if c.findtext("Cmd") == "12").sourceline
    out = tmp_path / "page.html"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "report", str(eni), "-o", str(out),
                           "--no-cache", "--esi", str(EXAMPLES / "tree" / "esi"),
                           "--esi", str(EXAMPLES / "esi")],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    rows = html.fromstring(out.read_text()).xpath("//tr[@class='finding']")
    cells = [[td.text_content() for td in r.findall("td")] for r in rows]
    assert [c[1] for c in cells] == ["ENI104"]
    assert cmd_line <= int(cells[0][2]) <= cmd_line + 20
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "report", str(eni), "-o", str(out),
                           "--no-cache", "--no-check"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    page = html.fromstring(out.read_text())
    assert page.get_element_by_id("not-checked") is not None


# ------------------------------------------------------------------ a plant-sized page

def plant_topology(segments: int) -> str:
    """A line of ``segments`` couplers (the next on each one's Ethernet port C), each with
    twelve E-bus terminals, a junction whose Ethernet ports D and B hold two drives, and
    two output terminals on its E-bus port C: 18 slaves per segment."""
    lines = ["master: {name: plant, cycle_time_us: 2000}", "slaves:"]
    for s in range(segments):
        lines.append(f"  - {{name: 'Coupler {s}', device: EXB1100"
                     + (f", parent: 'Coupler {s - 1}', port: C}}" if s else "}"))
        lines += [f"  - {{name: 'Term {s}.{t}', device: {'EXB1018' if t % 2 else 'EXB2018'}}}"
                  for t in range(12)]
        lines += [f"  - {{name: 'Junction {s}', device: EXB1122}}",
                  f"  - {{name: 'Axis {s}a', device: EXD-402, parent: 'Junction {s}', port: D}}",
                  f"  - {{name: 'Axis {s}b', device: EXD-402, parent: 'Junction {s}', port: B}}",
                  f"  - {{name: 'Out {s}.0', device: EXB2018, parent: 'Junction {s}', port: C}}",
                  f"  - {{name: 'Out {s}.1', device: EXB2018}}"]
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def plant(tmp_path_factory) -> Path:
    """A compiled 216-slave tree (12 segments) from the example devices."""
    folder = tmp_path_factory.mktemp("plant")
    topology = folder / "plant.yaml"
    topology.write_text(plant_topology(12))
    eni = folder / "plant.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topology), "--esi",
                           str(EXAMPLES / "tree" / "esi"), "--esi", str(EXAMPLES / "esi"),
                           "-o", str(eni), "--no-cache"], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    return eni


# Type a name into the search box; where the row it selects (and, after following its link
# to the drawing, the slave's box) is, against the viewport, and what is at its centre.
_FOUND_JS = """() => {
  const row = document.querySelector('#slave-table tbody tr.current');
  if (!row) { return null; }
  const r = row.getBoundingClientRect(), cx = (r.left + r.right) / 2,
        cy = (r.top + r.bottom) / 2, hit = document.elementFromPoint(cx, cy);
  return {name: row.querySelector('.row-name').textContent, id: row.dataset.slave,
          rect: [r.left, r.top, r.right, r.bottom], w: innerWidth, h: innerHeight,
          onTop: !!hit && row.contains(hit)};
}"""
_BOX_JS = """id => {
  const r = document.querySelector(`#topology-svg g.node[data-slave="${id}"] rect`)
    .getBoundingClientRect();
  return [r.left, r.top, r.right, r.bottom, innerWidth, innerHeight];
}"""


def _inside(rect: list[float], width: float, height: float) -> bool:
    return rect[0] >= -0.5 and rect[1] >= -0.5 and rect[2] <= width + 0.5 \
        and rect[3] <= height + 0.5 and rect[2] > rect[0] and rect[3] > rect[1]


# The same search and link, done in the page for every name in one call: as fill() does,
# the box's value is set and an "input" event sent; as a click on the link does, the link's
# click() follows it (a same-page fragment: the scroll happens before click() returns).
_FIND_ALL_JS = """([names, boxes]) => {
  const find = new Function('return (' + %s + ')')();
  const box = new Function('return (' + %s + ')')();
  const input = document.getElementById('slave-search');
  return names.map(name => {
    input.value = name;
    input.dispatchEvent(new Event('input', {bubbles: true}));
    const found = find();
    if (!found || !boxes) { return [found, null]; }
    document.querySelector(`#slave-table tr[data-slave="${found.id}"] a.to-box`).click();
    return [found, box(found.id)];
  });
}""" % (repr(_FOUND_JS), repr(_BOX_JS))

# Names typed and links clicked through Playwright as a user would (key events, a real
# click that waits until the link can be clicked): every this many-th name, and the last.
USER_SAMPLE_EVERY = 10


def _check_found(name: str, found: Any, box: list[float] | None) -> None:
    # The page's search ignores whitespace (an input drops line breaks in names).
    assert found is not None and found["name"].split() == name.split(), (name, found)
    assert _inside(found["rect"], found["w"], found["h"]) and found["onTop"], found
    if box is not None:
        *rect, w, h = box
        assert _inside(rect, w, h), (name, box)


def check_fits_and_finds(browser: Any, page_file: Path, names: list[str],
                         boxes: bool) -> None:
    """No horizontal overflow of the page; every slave, its name typed into the search
    box, is the selected row, inside the viewport and not covered; with ``boxes``, the
    row's link to the drawing brings the slave's box into the viewport.  Every name is
    searched in the page; a sample of them through Playwright's own typing and clicking."""
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.goto(page_file.resolve().as_uri(), wait_until="load")
    for width in (1280, 900):
        page.set_viewport_size({"width": width, "height": 800})
        assert page.evaluate("document.documentElement.scrollWidth") <= width
        assert page.evaluate("document.body.scrollWidth") <= width
    for name, (found, box) in zip(names, page.evaluate(_FIND_ALL_JS, [names, boxes])):
        _check_found(name, found, box)
    sample = names[::USER_SAMPLE_EVERY] + names[-1:]
    for name in sample:
        page.fill("#slave-search", name)
        found = page.evaluate(_FOUND_JS)
        box = None
        if boxes and found is not None:
            page.click(f'#slave-table tr[data-slave="{found["id"]}"] a.to-box')
            box = page.evaluate(_BOX_JS, found["id"])
        _check_found(name, found, box)
    page.close()


def test_plant_of_200_slaves_fits_and_every_slave_is_found(browser, tmp_path, plant):
    out = tmp_path / "plant.html"
    done = write_report(plant, out)
    assert done.returncode == 0, done.stderr
    slaves, _ = xml_names(plant)
    assert len(slaves) == 216
    opened = Opened(browser, out)
    opened.clean()
    check_drawing(opened, slaves)
    links = drawn_links(opened)
    check_rails(links, xml_ebus_links(plant))
    # Compact: the drawing's height per slave is well under the old one-row-per-slave's 38.
    height = opened.page.eval_on_selector("#topology-svg",
                                          "s => s.getBoundingClientRect().height")
    assert height < 24 * len(slaves)
    opened.page.close()
    check_fits_and_finds(browser, out, slaves, boxes=True)


@pytest.mark.parametrize("name", CORPUS_ENIS)
def test_corpus_page_fits_and_every_slave_is_found(request, browser, tmp_path, name):
    eni = corpus_eni(request, name)
    out = tmp_path / "network.html"
    assert write_report(eni, out).returncode == 0
    slaves, _ = xml_names(eni)
    # Names the ENI gives twice (a search selects the first) are looked for once.
    check_fits_and_finds(browser, out, [n for n in slaves if slaves.count(n) == 1],
                         boxes=True)


# ------------------------------------------- working-counter shares, device types, checks

SHARE_ENIS = CORPUS_ENIS + ["corpus-extra/pmec-lupa/LUPA1kHz_DC.xml",
                            "corpus/acontis-ecmaster-demo-motion/Yaskawa_SGDV_1ms.xml"]


def _shares(page: Any) -> list[tuple[int, list[tuple[str, int]], str]]:
    """Per datagram row: the sum, (slave, +n) of each share, the summary's words."""
    out = []
    for td in page.xpath("//table[@class='frame']//td[contains(@class, 'shares')]"):
        items = [(li.xpath("string(.//span[@class='share-name'])"),
                  int(li.xpath("string(.//b[@class='share-adds'])"))) for li in td.xpath(".//li")]
        out.append((int(td.get("data-sum")), items, td.xpath("string(.//summary)")))
    return out


@pytest.mark.parametrize("name", SHARE_ENIS)
def test_shares_add_up_to_the_tools_working_counter(request, name):
    """The slaves each datagram serves add up to the Cnt the tool that wrote the ENI
    (TwinCAT, EC-Engineer) computed, for every cyclic command that has one."""
    eni = corpus_eni(request, name)
    page = html.fromstring(report.render(read_file(eni), str(eni), None))
    root = etree.parse(str(eni)).getroot()
    cnts = [c.findtext("Cnt") for c in root.findall("Config/Cyclic/Frame/Cmd")]
    shares = _shares(page)
    assert len(shares) == len(cnts) and any(cnts)
    for (total, items, words), cnt in zip(shares, cnts):
        assert total == sum(n for _, n in items)
        if cnt is not None:
            assert total == int(cnt) and "equal to the ENI's Cnt" in words, (cnt, words)
        else:
            assert "gives no expected working counter" in words


def test_shares_per_slave_follow_the_process_data(tmp_path):
    """In the compiled tree, the LRW serves each slave whose ProcessData Send (outputs:
    +2) or Recv (inputs: +1) range it covers (ETG.1000.4; read by lxml); the BRD every
    slave (+1).  A Cnt made wrong: the page says the sum differs."""
    tree = etree.parse(str(compiled_tree(tmp_path)))
    root = tree.getroot()
    want: dict[str, int] = {}
    for slave in root.findall("Config/Slave"):
        adds = sum(2 if tag == "Send" else 1 for tag in ("Send", "Recv")
                   if any(int(r.findtext("BitLength"))
                          for r in slave.findall(f"ProcessData/{tag}")))
        if adds:
            want[slave.findtext("Info/Name")] = adds
    cmds = root.findall("Config/Cyclic/Frame/Cmd")
    lrw = next(k for k, c in enumerate(cmds) if c.findtext("Cmd") == "12")
    brd = next(k for k, c in enumerate(cmds) if c.findtext("Cmd") == "7")
    cmds[lrw].find("Cnt").text = str(int(cmds[lrw].findtext("Cnt")) + 1)
    eni = tmp_path / "wkc.eni.xml"
    tree.write(str(eni), xml_declaration=True, encoding="UTF-8")
    shares = _shares(html.fromstring(report.render(read_file(eni), str(eni), None)))
    assert dict(shares[lrw][1]) == want
    assert f"differs from the ENI's Cnt {sum(want.values()) + 1}" in shares[lrw][2]
    names = [s.findtext("Info/Name") for s in root.findall("Config/Slave")]
    assert shares[brd][1] == [(n, 1) for n in names]


def test_boxes_show_the_enis_device_types(request, browser, tmp_path):
    """TwinCAT's ProductRevision (lxml) is the type in each box that has one; a slave
    without it shows its product code; the vendor is its id without an ESI."""
    eni = corpus_eni(request, "corpus-extra/pmec-wec-bench/DriveAndDUTAndPAAndLoadXML.xml")
    out = tmp_path / "pmec.html"
    assert write_report(eni, out).returncode == 0
    opened = Opened(browser, out)
    shown = opened.page.eval_on_selector_all(
        "#topology-svg g.node[data-slave]",
        "gs => gs.map(g => [+g.dataset.slave, g.querySelector('text.type').textContent, "
        "g.querySelector('text.where').textContent])")
    slaves = etree.parse(str(eni)).getroot().findall("Config/Slave")
    assert len(shown) == len(slaves)
    for index, kind, where in shown:
        info = slaves[index].find("Info")
        revision = info.findtext("ProductRevision")
        expected = revision or f"product 0x{int(info.findtext('ProductCode')):X}"
        # A line longer than the box shows is cut, with an ellipsis.
        assert kind and expected.startswith(kind.removesuffix("\u2026")), (kind, expected)
        at = "passive" if info.find("PhysAddr") is None else \
            f"#{-int(info.findtext('AutoIncAddr')) & 0xFFFF} @{info.findtext('PhysAddr')}"
        full = f"{at} vendor 0x{int(info.findtext('VendorId')):X}"
        assert full.startswith(where.removesuffix("\u2026")) and len(where) > len(at), \
            (where, full)
    assert any(info.findtext("ProductRevision") for info in
               (s.find("Info") for s in slaves))
    opened.page.close()


def _esi_device(product_code: int) -> tuple[str, str]:
    """(Type, Vendor/Name) of the example ESI device with that product code, by lxml."""
    for path in sorted((EXAMPLES / "tree" / "esi").glob("*.xml")) + sorted(
            (EXAMPLES / "esi").glob("*.xml")):
        root = etree.parse(str(path)).getroot()
        for dev in root.iter("Device"):
            code = dev.find("Type").get("ProductCode")
            if code and int(code.replace("#x", "0x"), 0) == product_code:
                return dev.findtext("Type").strip(), root.findtext("Vendor/Name").strip()
    raise AssertionError(product_code)


ESI_ARGS = ("--esi", str(EXAMPLES / "tree" / "esi"), "--esi", str(EXAMPLES / "esi"))


def test_with_esi_the_boxes_and_the_checks_line_name_the_devices(tmp_path):
    """With --esi: each slave's type and vendor name from its ESI device (read by lxml),
    and 'device rules ran for all 7 slaves'; a slave whose revision no ESI describes is
    named as skipped; without --esi the line says the device rules were skipped."""
    eni = compiled_tree(tmp_path)
    out = tmp_path / "tree.html"
    done = write_report(eni, out, *ESI_ARGS)
    assert done.returncode == 0, done.stderr
    page = html.fromstring(out.read_text())
    slaves = etree.parse(str(eni)).getroot().findall("Config/Slave")
    for row in page.xpath("//table[@id='slave-table']/tbody/tr"):
        info = slaves[int(row.get("data-slave"))].find("Info")
        kind, vendor = _esi_device(int(info.findtext("ProductCode")))
        cells = [td.text_content() for td in row.findall("td")]
        assert cells[3:5] == [kind, vendor], cells
    line = page.get_element_by_id("checks-ran").text_content()
    assert f"device rules ran for all {len(slaves)} slaves" in line
    assert "found nothing." in page.get_element_by_id("no-findings").text_content()
    # One slave's revision changed: no ESI describes it.
    tree = etree.parse(str(eni))
    axis3 = next(s for s in tree.getroot().findall("Config/Slave")
                 if s.findtext("Info/Name") == "axis3")
    axis3.find("Info/RevisionNo").text = "4242"
    other = tmp_path / "other.eni.xml"
    tree.write(str(other), xml_declaration=True, encoding="UTF-8")
    assert write_report(other, out, *ESI_ARGS).returncode == 0
    page = html.fromstring(out.read_text())
    line = page.get_element_by_id("checks-ran").text_content()
    assert (f"device rules ran for {len(slaves) - 1} of {len(slaves)} slaves; skipped: "
            f"no ESI for 1 of {len(slaves)} slaves") in line
    assert "axis3" in page.xpath("string(//details[summary[starts-with(., 'Slaves without')]])")
    assert write_report(eni, out).returncode == 0
    line = html.fromstring(out.read_text()).get_element_by_id("checks-ran").text_content()
    assert "device rules skipped: no ESI given" in line


def test_shares_are_what_the_emulated_slaves_count(tmp_path):
    """The compiled tree cycling in OP on the virtual segment (slaves emulated from the
    example ESIs): each cyclic command's working counter as the emulated ESCs returned it
    equals the page's sum of shares, the ARMW of the DC system time and the broadcasts
    included."""
    from ecatcfg.runtime.network import Network
    eni = compiled_tree(tmp_path)
    plan = read_file(eni)
    page = html.fromstring(report.render(plan, str(eni), None))
    sums = [total for total, _, _ in _shares(page)]
    cmds = [c for cy in plan.cyclic for f in cy.frames for c in f.cmds]
    assert any(c.cmd == 13 for c in cmds)                     # ARMW
    with Network.virtual(plan, [EXAMPLES / "tree" / "esi", EXAMPLES / "esi"],
                         esi_cache=False) as net:
        net.up()
        assert net.cycle() and net.cycle()
        returned = {id(s.cmd): s.wkc for slots in net.master.cyclic.frames for s in slots}
    compared = [(c, total) for c, total in zip(cmds, sums) if id(c) in returned]
    assert len(compared) >= len(cmds) - 1 and any(c.cmd == 13 for c, _ in compared)
    for c, total in compared:
        assert returned[id(c)] == total, (c.cmd, c.adp, c.ado, c.addr)
