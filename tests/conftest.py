"""Shared fixtures.  Corpus-dependent tests skip locally when the corpus is missing, but fail
in CI (CI=true, or ECATCFG_REQUIRE_CORPUS=1 as `.ci/run` sets): nothing silently skips there
(``prereq.py``)."""

from __future__ import annotations

import os
from pathlib import Path

import prereq
import pytest
from rig import pysoem_module, tshark_path, veth_netns  # noqa: F401  (runtime test rig fixtures)

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
FIXTURES = Path(__file__).resolve().parent / "fixtures"
CORPUS = Path(os.environ.get("ECATCFG_CORPUS", ROOT.parent / "shared" / "corpus"))
# More real files, kept beside the corpus (its MANIFEST.md says what each is).
CORPUS_EXTRA = Path(os.environ.get("ECATCFG_CORPUS_EXTRA",
                                   ROOT.parent / "shared" / "corpus-extra"))


def _require(what: str) -> None:
    prereq.missing(what, "not found (set ECATCFG_CORPUS to its folder)", prereq.CORPUS)


@pytest.fixture(scope="session")
def corpus() -> Path:
    if not (CORPUS / "esi").is_dir():
        _require(f"the corpus at {CORPUS}")
    return CORPUS


@pytest.fixture(scope="session")
def corpus_extra() -> Path:
    """The second corpus (more vendor ESIs and ENIs), skipped or failed like the first."""
    if not (CORPUS_EXTRA / "eni").is_dir() or not (CORPUS_EXTRA / "esi").is_dir():
        prereq.missing(f"the extra corpus at {CORPUS_EXTRA}",
                       "not found (set ECATCFG_CORPUS_EXTRA to its folder)", prereq.CORPUS)
    return CORPUS_EXTRA


# Every ENI of both corpora, named "<corpus>/<path below its eni/>", found by globbing (a
# placeholder when a corpus is missing, so that its tests skip or fail rather than vanish).
CORPORA = {"corpus": CORPUS, "corpus-extra": CORPUS_EXTRA}


def corpus_enis() -> list[str]:
    found = []
    for name, root in CORPORA.items():
        enis = sorted(p.relative_to(root / "eni").as_posix()
                      for p in (root / "eni").rglob("*.xml"))
        found += [f"{name}/{e}" for e in enis] or [f"{name}/(missing)"]
    return found


def corpus_eni(request: pytest.FixtureRequest, eni: str) -> Path:
    """The file of ``corpus_enis()``'s ``eni`` through its corpus' fixture (which skips or
    fails when the corpus is missing)."""
    name, below = eni.split("/", 1)
    return request.getfixturevalue(name.replace("-", "_")) / "eni" / below


def plan_or_refused(path: Path):
    """The plan of a corpus ENI for the export sweeps, or None when the reader refuses it
    (tests/test_eni_io.py says why); then it is checked to be refused by name, as every
    export reads it the same way: nothing CI can provide may skip."""
    from ecatcfg.eni.reader import read_file
    from ecatcfg.errors import EcatcfgError
    try:
        return read_file(path)
    except EcatcfgError as exc:
        assert str(path) in str(exc), exc
        return None


@pytest.fixture(scope="session")
def esi_schema(corpus: Path):
    from lxml import etree
    xsd = corpus / "schemas" / "esi-1.17" / "EtherCATInfo.xsd"
    if not xsd.is_file():
        _require(str(xsd))
    return etree.XMLSchema(etree.parse(str(xsd)))


@pytest.fixture(scope="session")
def eni_schema(corpus: Path):
    from lxml import etree
    xsd = corpus / "schemas" / "eni-1.3" / "EtherCATConfig.xsd"
    if not xsd.is_file():
        _require(str(xsd))
    return etree.XMLSchema(etree.parse(str(xsd)))


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    """Every test gets its own empty index cache: never the user's ~/.cache."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("xdg-cache")))


@pytest.fixture(autouse=True)
def _simulated_time(request, monkeypatch):
    """In-memory networks (``Network.virtual``) run on simulated time in tests: every one a
    test makes without a ``clock`` gets a fresh ``SimClock`` (runtime/simwire.py), so a
    busy host cannot make a reply late or a watchdog expire.  A test where real time is
    the point (a background run timed by the host, real-time jitter) is marked
    ``wallclock``.  Only where the runtime is imported already: a test of something else
    does not load it."""
    import sys
    if request.node.get_closest_marker("wallclock") or \
            "ecatcfg.runtime.network" not in sys.modules:
        return
    from ecatcfg.runtime.clock import SimClock
    from ecatcfg.runtime.network import Network
    virtual = Network.__dict__["virtual"].__func__

    def simulated(cls, *args, clock=None, **kwargs):
        return virtual(cls, *args, clock=SimClock() if clock is None else clock, **kwargs)
    monkeypatch.setattr(Network, "virtual", classmethod(simulated))


def write(tmp_path: Path, name: str, text: str | bytes) -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


# A minimal, valid ESI body for fixtures; {devices} is replaced by Device elements.
ESI_TEMPLATE = """<?xml version="1.0" encoding="{encoding}"?>
<EtherCATInfo Version="1.17">
  <Vendor><Id>{vendor}</Id><Name>Fixture Vendor</Name></Vendor>
  <Descriptions>
    <Groups><Group><Type>G</Type><Name>Group</Name></Group></Groups>
    <Devices>
{devices}
    </Devices>
  </Descriptions>
</EtherCATInfo>
"""


def device_xml(type_name: str = "FX1", product: str = "#x10", revision: str = "#x1",
               body: str = "") -> str:
    return (f'      <Device Physics="YY"><Type ProductCode="{product}" RevisionNo="{revision}">'
            f'{type_name}</Type><Name LcId="1033">{type_name} name</Name>'
            f"<GroupType>G</GroupType>{body}</Device>")


def esi_xml(*devices: str, vendor: str = "#x00E0F1", encoding: str = "UTF-8") -> str:
    return ESI_TEMPLATE.format(devices="\n".join(devices) or device_xml(), vendor=vendor,
                               encoding=encoding)


def compile_example(eni: Path) -> Path:
    """``ecatcfg compile`` of the example topology (examples/) into ``eni``, as a user runs it."""
    import subprocess
    import sys
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile",
                           str(EXAMPLES / "topology.yaml"), "--esi", str(EXAMPLES / "esi"),
                           "-o", str(eni), "--no-cache"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    return eni


@pytest.fixture(scope="module")
def example_plan():
    """The example topology compiled, written and read back: the runtime gets what the file
    says, not the compiler's objects."""
    from ecatcfg.compiler import build, topology
    from ecatcfg.eni import reader as eni_reader, writer as eni_writer
    from ecatcfg.esi.library import Library
    plan = build.compile_topology(topology.load(EXAMPLES / "topology.yaml"),
                                  Library([EXAMPLES / "esi"], cache=False)).plan
    return eni_reader.read_bytes(eni_writer.to_bytes(plan), "example.eni.xml")


def _pdo_entry(index: int, bits: int, type_: str) -> str:
    return (f"<Entry><Index>#x{index:04X}</Index><SubIndex>1</SubIndex><BitLen>{bits}"
            f"</BitLen><Name>e</Name><DataType>{type_}</DataType></Entry>")


# A device body with a 128-byte mailbox (SM0/SM1), one byte of outputs (SM2, 0x1600) and one
# of inputs (SM3, 0x1A00): add a <Mailbox> with the protocols a test needs.
MAILBOX_PD_SMS = (
    '<Fmmu>Outputs</Fmmu><Fmmu>Inputs</Fmmu>'
    '<Sm ControlByte="#x26" DefaultSize="128" Enable="1" StartAddress="#x1000">MBoxOut</Sm>'
    '<Sm ControlByte="#x22" DefaultSize="128" Enable="1" StartAddress="#x1080">MBoxIn</Sm>'
    '<Sm ControlByte="#x64" Enable="1" StartAddress="#x1100">Outputs</Sm>'
    '<Sm ControlByte="#x20" Enable="1" StartAddress="#x1180">Inputs</Sm>'
    '<RxPdo Fixed="1" Mandatory="1" Sm="2"><Index>#x1600</Index><Name>Out</Name>'
    f'{_pdo_entry(0x7000, 8, "USINT")}</RxPdo>'
    '<TxPdo Fixed="1" Mandatory="1" Sm="3"><Index>#x1A00</Index><Name>In</Name>'
    f'{_pdo_entry(0x6000, 8, "USINT")}</TxPdo>')


class FifoUnblock:
    """Opens ``fifo`` from both ends after ``seconds`` if the code under test still waits on
    it (a regression would otherwise hang the suite): ``needed`` says it had to."""

    def __init__(self, fifo: Path, seconds: float = 20) -> None:
        import threading
        self.needed = False
        self._done = threading.Event()
        self._fifo = fifo
        self._thread = threading.Thread(target=self._run, args=(seconds,), daemon=True)
        self._thread.start()

    def _run(self, seconds: float) -> None:
        wait = seconds
        while not self._done.wait(wait):
            self.needed = True
            wait = 0.5          # and again, for as long as it goes on opening it
            try:                # O_RDWR on a FIFO never blocks (Linux) and wakes both ends
                os.close(os.open(self._fifo, os.O_RDWR | os.O_NONBLOCK))
            except OSError:
                pass

    def __enter__(self) -> FifoUnblock:
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._thread.join()


# -- known refusals of the corpus sweeps (tests/known_refusals.py) ----------------------------
# A listed case runs as any other; it must fail with the failure its entry names, and then
# counts as an expected failure with the entry's reason.  A listed case that passes, or
# fails otherwise, fails the run.

def _known_key(nodeid: str) -> str:
    """A test's id as known_refusals.py names it, from the checkout: pytest started from
    another folder (bench/mutation.py runs the tests of a copy from the folder above it,
    ``ecatcfg/tests/...``) puts that folder in front."""
    at = nodeid.find("/tests/", 0, nodeid.find("::") if "::" in nodeid else len(nodeid))
    return nodeid[at + 1:] if at >= 0 else nodeid


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]):
    outcome = yield
    report = outcome.get_result()
    if call.when != "call":
        return
    from known_refusals import KNOWN
    known = KNOWN.get(_known_key(item.nodeid))
    if known is None:
        return
    import re
    where = "tests/known_refusals.py"
    if report.passed:
        report.outcome = "failed"
        report.longrepr = (f"{item.nodeid} passes now: take its entry out of {where} "
                           f"(it was: {known.reason}; removed by {known.until})")
    elif report.failed and call.excinfo is not None:
        text = f"{call.excinfo.typename}: {call.excinfo.value}"
        if re.search(known.failure, text, re.S):
            report.outcome = "skipped"
            report.wasxfail = f"known refusal: {known.reason} (until {known.until})"
        else:
            report.longrepr = (f"{report.longrepr}\n\n{item.nodeid} is listed in {where} as "
                               f"failing with /{known.failure}/ ({known.reason}), "
                               "but failed otherwise")


def pytest_collection_finish(session: pytest.Session) -> None:
    """Every entry of known_refusals.py names a case that exists (when its file was
    collected whole): a renamed test or a removed corpus file must take its entry along."""
    from known_refusals import KNOWN
    ids = {_known_key(item.nodeid) for item in session.items}
    files = {nodeid.split("::", 1)[0] for nodeid in ids}
    stale = [k for k in KNOWN if k.split("::", 1)[0] in files and k not in ids
             and not session.config.option.keyword and not session.config.option.markexpr
             and all("::" not in str(a) for a in session.config.args)]
    if stale:
        raise pytest.UsageError("tests/known_refusals.py names cases that do not exist: "
                                + ", ".join(stale))


# The files whose tests take 10 s or more each on the 2-core machine (`--durations`):
# collected first, so that pytest-xdist's workers start on them and share what remains
# (worksteal), instead of one worker finishing such a test alone after the other is done
# (test_wheel.py sorts last by name and held the suite's tail).  Only the order changes.
HEAVY_FIRST = ("test_wheel.py", "test_doc_examples.py", "test_report.py", "test_lint_corpus.py",
               "test_agreement.py", "test_fuzz.py", "test_diagnosis_agreement.py",
               "test_export_soem_c.py", "test_synclink.py")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    rank = {name: k for k, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))     # stable
