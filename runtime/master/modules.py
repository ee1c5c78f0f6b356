"""The plugged modules of a modular station, checked against the ENI before SAFEOP.

An ENI configures a station (Weidmueller UR20, UTRIO UC20, a drive with axis modules) with
the configured module ident list, 0xF030, one UDINT per module position (ETG.5001 modular
device profile; the compiler writes it where the ESI asks, ``Slots@DownloadModuleIdentList``).
The station reports the modules it found in 0xF050, the detected module ident list (a
station without that object is not checked).  Before
the mailbox InitCmds of the transition that downloads 0xF030 (PREOP->SAFEOP), the master
uploads 0xF050 and stops with a table of the positions that differ: a station whose modules
were swapped or removed would otherwise go on with a process image that no longer fits
(or fail later with a bare SDO abort on a module object that is not there).
"""

from __future__ import annotations

import re

from ecatcfg.eni.plan import SlavePlan
from ecatcfg.esc import DETECTED_MODULE_IDENT_LIST, MODULE_IDENT_LIST, Transition
from ecatcfg.esi.slots import ident_list_from_writes
from ecatcfg.runtime.master.lockstep import Job
from ecatcfg.runtime.master.replay import ApplyError, MailboxChannel, sdo_job

# A module PDO's name as the ENI gives it: "Module 3 (UR20-4DI-P / 1315170000).Input".
_MODULE_PDO = re.compile(r"^Module (\d+) \((.*)\)\.[^.]*$")


def configured_modules(slave: SlavePlan, transition: Transition) -> dict[int, int]:
    """Position -> ident of the 0xF030 downloads the ENI makes in ``transition``."""
    coe = slave.mailbox.coe_init_cmds if slave.mailbox else []
    return ident_list_from_writes([(c.subindex, c.data, c.complete_access) for c in coe
                                   if c.index == MODULE_IDENT_LIST and c.ccs == 1
                                   and not c.disabled and transition in c.transitions])


def module_names(slave: SlavePlan) -> dict[int, str]:
    """Position -> module name from the ENI's module PDO names, where it has them."""
    names: dict[int, str] = {}
    for pdo in slave.process_data.pdos if slave.process_data else []:
        m = _MODULE_PDO.match(pdo.name)
        if m:
            names.setdefault(int(m.group(1)), m.group(2))
    return names


def check_modules(channel: MailboxChannel, slave: SlavePlan, transition: Transition,
                  who: str) -> Job:
    """Upload 0xF050 and compare it with the ENI's 0xF030 of ``transition``; nothing to do
    for a slave whose ENI downloads no module ident list then."""
    from ecatcfg.runtime.mailbox import ABORT_NO_OBJECT
    from ecatcfg.runtime.master.sdo_client import SdoUpload

    expected = configured_modules(slave, transition)
    if not expected:
        return
    what = "check detected modules (0xF050)"
    size = channel.plan.send.length

    def upload(subindex: int) -> Job:
        t = SdoUpload(DETECTED_MODULE_IDENT_LIST, subindex, False, size, channel.counter)
        yield from sdo_job(channel, t, who, what)
        found[subindex] = int.from_bytes(t.result[:4], "little")

    found: dict[int, int] = {}
    try:
        yield from upload(0)
    except ApplyError as exc:
        # 0xF050 is optional (ETG.5001): a station without it cannot be checked.
        if exc.abort_code == ABORT_NO_OBJECT:
            return
        raise
    count = found.pop(0) & 0xFF
    for sub in range(1, count + 1):
        yield from upload(sub)
    last = max(max(expected, default=0), count)
    rows = [(n, expected.get(n, 0), found.get(n, 0)) for n in range(1, last + 1)]
    if any(want != got for _, want, got in rows):
        raise ApplyError("the plugged modules differ from the configuration (0xF030 "
                         "configured, 0xF050 detected):\n"
                         + module_table(rows, module_names(slave)), who, what)


def module_table(rows: list[tuple[int, int, int]], names: dict[int, str]) -> str:
    """Position, expected ident and name, found ident; differing rows marked ``<<``."""
    width = max([len(names.get(n, "")) for n, _, _ in rows] + [4])
    lines = [f"  {'pos':>3}  {'expected':<10}  {'name':<{width}}  found"]
    for n, want, got in rows:
        mark = "  <<" if want != got else ""
        lines.append(f"  {n:>3}  {_ident(want):<10}  {names.get(n, ''):<{width}}  "
                     f"{_ident(got):<10}{mark}")
    return "\n".join(lines)


def _ident(ident: int) -> str:
    return f"0x{ident:08X}" if ident else "(none)"
