"""``ecatcfg report``: an ENI's network as one self-contained HTML page.

Everything on the page comes from the ENI as read into a :class:`NetworkPlan` (any tool's
file): the topology drawn as SVG, E-bus terminals side by side as on the DIN rail
(:mod:`.network_tree`), each box with its device type and vendor (:mod:`.report_devices`),
a searchable slave table and a table per slave, the process image as a map of bytes and
bits coloured by slave (:mod:`.image_map`), the cyclic frames with their expected working
counters, the slaves each datagram serves and what each adds (:mod:`.wkc_shares`), and
slave-to-slave copies, each slave's InitCmds per transition in the words of ``show``
(:mod:`.show`, :mod:`.words`), what ``apply`` does not do, which check rules ran and the
findings of ``check`` (lint's :class:`~ecatcfg.esi.lint.finding.Finding`).

The page loads nothing: CSS, the SVG and a few lines of script are inline, and its
Content-Security-Policy forbids any fetch, so it opens the same from a ticket attachment on
a laptop without a network.  The template is ``templates/network_report.html.j2``.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from ecatcfg.eni.image_map import ImageMap, bit_owners, image_map
from ecatcfg.eni.network_tree import BOX_H, BOX_W, LINE_CHARS, Drawing, layout
from ecatcfg.eni.plan import BitRange, NetworkPlan, PassiveSlave, SlavePlan
from ecatcfg.eni.report_devices import CheckCoverage, DeviceLabel
from ecatcfg.eni.show import EniView, summary
from ecatcfg.eni.wkc_shares import CommandShares, frame_shares
from ecatcfg.fileio import write_atomic
from ecatcfg.record import record

if TYPE_CHECKING:
    import jinja2

    from ecatcfg.esi.lint.finding import Finding

TEMPLATE = "network_report.html.j2"
_STATE = {"I": "INIT", "P": "PREOP", "S": "SAFEOP", "O": "OP", "B": "BOOT"}


@record
class SlaveCard:
    """One slave's table: ``(label, value)`` rows, its InitCmds per transition."""

    index: int
    name: str
    colour: str
    passive: bool
    rows: list[tuple[str, str]]
    init_cmds: dict[str, list[str]]


@record
class SlaveRow:
    """A row of the searchable slave table (and the lines of the slave's box)."""

    index: int
    name: str
    colour: str
    passive: bool
    position: str
    station: str
    identity: str
    type: str
    vendor: str
    in_bytes: int
    out_bytes: int
    variables: list[str]

    @property
    def box_lines(self) -> tuple[str, str]:
        """The box's second and third lines, cut to what a box shows."""
        where = "passive" if self.passive else f"#{self.position} @{self.station}"
        return (_cut(self.type or f"product 0x{int(self.identity.split(':')[1], 16):X}"),
                _cut(f"{where} {self.vendor}"))


def _cut(text: str) -> str:
    return text if len(text) <= LINE_CHARS else text[:LINE_CHARS - 1] + "\u2026"


@record
class VariableRow:
    name: str
    direction: str
    offset: str                              # byte.bit
    bit_size: int
    data_type: str
    owner: int | None


def colour(index: int) -> str:
    """A slave's colour: hues a golden angle apart, so neighbours never look alike, and
    three lightnesses in turn, so that hues that come round close again still differ."""
    return f"hsl({index * 137.508 % 360:.1f}, 70%, {(78, 68, 87)[index % 3]}%)"


def transition_title(code: str) -> str:
    """``IP`` -> ``IP (INIT -> PREOP)``."""
    return f"{code} ({_STATE.get(code[0], code[0])} \u2192 {_STATE.get(code[1], code[1])})"


def _hex(value: int, digits: int) -> str:
    return f"0x{value:0{digits}X}"


def _identity(s: SlavePlan | PassiveSlave) -> str:
    return (f"vendor {_hex(s.vendor_id, 8)}, product {_hex(s.product_code, 8)}, "
            f"revision {_hex(s.revision, 8)}")


def _slave_rows(s: SlavePlan | PassiveSlave, behind: str) -> list[tuple[str, str]]:
    if isinstance(s, PassiveSlave):
        return [("kind", "passive terminal (no ESC: no position, no station address)"),
                ("identity", _identity(s)), ("serial number", str(s.serial_no)),
                ("behind", behind)]
    rows = [("position", f"{s.position} (auto-increment address {s.auto_inc_addr})"),
            ("station address", str(s.phys_addr)), ("identity", _identity(s)),
            ("serial number", str(s.serial_no)), ("physics", s.physics),
            ("behind", behind)]
    mbx = s.mailbox
    if mbx is not None:
        rows.append(("mailbox", f"{', '.join(mbx.protocols) or 'no protocol named'}; "
                                f"out {_hex(mbx.send.start, 4)} len {mbx.send.length}, "
                                f"in {_hex(mbx.recv.start, 4)} len {mbx.recv.length}"))
    pd = s.process_data
    if pd is not None:
        names: dict[tuple[str, int], str] = {(p.direction, p.index): p.name for p in pd.pdos}
        for sm in pd.sms:
            # Outputs SyncManagers hold RxPDOs, Inputs ones TxPDOs (ETG.2100 ``SmN/Type``).
            kind = "rx" if sm.type.lower().startswith("out") else "tx"
            pdos = ", ".join(f"{_hex(i, 4)} {names.get((kind, i), '')}".rstrip()
                             for i in sm.pdos) or "no PDO"
            rows.append((f"sm {sm.number}", f"{sm.type} {_hex(sm.start_address, 4)} ctrl "
                                            f"{_hex(sm.control_byte, 2)}: {pdos}"))
        for label, ranges in (("outputs", pd.send), ("inputs", pd.recv)):
            for r in ranges:
                rows.append((label, f"bits {r.bit_start}-{r.bit_start + r.bit_length - 1} "
                                    f"(byte {r.bit_start // 8}.{r.bit_start % 8}, "
                                    f"{r.bit_length} bit)"))
    if s.dc is not None:
        rows.append(("DC", f"SYNC0 cycle {s.dc.cycle_time0} ns, SYNC1 cycle "
                           f"{s.dc.cycle_time1} ns, shift {s.dc.shift_time} ns"
                           + (", reference clock" if s.dc.reference_clock else "")))
    if s.hot_connect is not None:
        rows.append(("hot connect", f"heads a group of {s.hot_connect.member_count}"))
    return rows


def _cards(plan: NetworkPlan, view: EniView) -> list[SlaveCard]:
    cards = []
    for k, (s, shown) in enumerate(zip(plan.in_file_order(), view.slaves)):
        behind = "the master" if shown.parent is None else \
            repr(shown.parent) + (f" port {shown.port}" if shown.port else "")
        cards.append(SlaveCard(k, s.name, colour(k), isinstance(s, PassiveSlave),
                               _slave_rows(s, behind), shown.init_cmds))
    return cards


def _bytes(ranges: Sequence[BitRange]) -> int:
    return (sum(r.bit_length for r in ranges) + 7) // 8


def _slave_table(plan: NetworkPlan, variables: list[VariableRow],
                 labels: list[DeviceLabel]) -> list[SlaveRow]:
    owned: dict[int, list[str]] = {}
    for v in variables:
        if v.owner is not None:
            owned.setdefault(v.owner, []).append(v.name)
    rows = []
    for k, s in enumerate(plan.in_file_order()):
        label = labels[k] if k < len(labels) else DeviceLabel("", f"vendor 0x{s.vendor_id:X}", None)
        pd = s.process_data if isinstance(s, SlavePlan) else None
        rows.append(SlaveRow(
            k, s.name, colour(k), isinstance(s, PassiveSlave),
            "" if isinstance(s, PassiveSlave) else str(s.position),
            "" if isinstance(s, PassiveSlave) else str(s.phys_addr),
            f"{_hex(s.vendor_id, 8)}:{_hex(s.product_code, 8)}:{_hex(s.revision, 8)}",
            label.type, label.vendor,
            _bytes(pd.recv) if pd is not None else 0, _bytes(pd.send) if pd is not None else 0,
            owned.get(k, [])))
    return rows


def _variables(plan: NetworkPlan, view: EniView) -> list[VariableRow]:
    owners = {d: bit_owners(plan, d) for d in ("in", "out")}
    return [VariableRow(v.name, v.direction, v.offset, v.bit_size, v.data_type or "",
                        owners[v.direction].get(v.bit_offs)) for v in view.variables]


@functools.cache
def _template() -> jinja2.Template:
    import jinja2
    folder = resources.files("ecatcfg.templates")
    env = jinja2.Environment(
        loader=jinja2.FunctionLoader(lambda name: folder.joinpath(name).read_text("utf-8")),
        autoescape=True, keep_trailing_newline=True, trim_blocks=True, lstrip_blocks=True,
        undefined=jinja2.StrictUndefined)
    env.filters["transition"] = transition_title
    return env.get_template(TEMPLATE)


def render(plan: NetworkPlan, file: str, findings: Sequence[Finding] | None,
           labels: list[DeviceLabel] | None = None,
           coverage: CheckCoverage | None = None) -> bytes:
    """The page for ``plan`` read from ``file``.  ``findings``: what ``check`` found in
    it, shown in their own section; ``None`` when check was not run (the page says so
    rather than show an empty list as a clean result).  ``labels``: each slave's device
    type and vendor (``report_devices.labels``); ``coverage``: which check rules ran."""
    view = summary(plan, file)
    drawing: Drawing = layout(plan)
    maps: list[ImageMap] = [image_map(plan, "in"), image_map(plan, "out")]
    order = plan.in_file_order()
    variables = _variables(plan, view)
    table = _slave_table(plan, variables, labels or [])
    shares: list[list[CommandShares]] = frame_shares(plan)
    text = _template().render(
        file=file, plan=plan, view=view, drawing=drawing, box_w=BOX_W, box_h=BOX_H,
        cards=_cards(plan, view), maps=maps, variables=variables, table=table,
        shares=shares, coverage=coverage,
        names=[s.name for s in order], colours=[colour(k) for k in range(len(order))],
        findings=None if findings is None else sorted(findings, key=lambda f: f.sort_key()))
    return text.encode("utf-8")


def write(plan: NetworkPlan, path: str | Path, file: str,
          findings: Sequence[Finding] | None, labels: list[DeviceLabel] | None = None,
          coverage: CheckCoverage | None = None) -> None:
    """Render and write atomically (``fileio.write_atomic``)."""
    write_atomic(path, render(plan, file, findings, labels, coverage))
