"""Register InitCmds of a compiled slave: what its ESI and the topology say, given to the
standard set-up (:mod:`ecatcfg.eni.standard`, the one place the commands, their order and
their comments are written; a partial ENI is completed by the same rule,
:mod:`ecatcfg.eni.derive`)."""

from __future__ import annotations

from ecatcfg.compiler.layout import SlaveLayout, pd_bits
from ecatcfg.compiler.resolve import ResolvedSlave
from ecatcfg.eni.plan import DcPlan, InitCmd
from ecatcfg.eni.standard import PdSm, SlaveSetup, master_init_cmds, pd_sm_config, \
    slave_init_cmds as standard_init_cmds
from ecatcfg.esc import SmConfig

__all__ = ["master_init_cmds", "slave_init_cmds"]


def slave_init_cmds(slave: ResolvedSlave, lay: SlaveLayout, dc: DcPlan | None,
                    assign_activate: int, bootstrap: tuple[SmConfig, SmConfig] | None
                    ) -> list[InitCmd]:
    return standard_init_cmds(setup(slave, lay, dc, assign_activate, bootstrap))


def setup(slave: ResolvedSlave, lay: SlaveLayout, dc: DcPlan | None, assign_activate: int,
          bootstrap: tuple[SmConfig, SmConfig] | None) -> SlaveSetup:
    """The slave as the standard set-up needs it: identity and addresses, its mailbox and
    process-data SyncManagers from the ESI (``OpOnly`` included), the FMMUs of the layout,
    DC, the ESI's state-machine timeouts, the topology's alias and watchdogs."""
    dev = slave.device
    info = dev.info
    mailbox = [sm for sm in dev.sms if sm.is_mailbox]
    out, inp = pd_bits(slave)
    outputs = {n for n, _ in out}
    sms = {sm.number: sm for sm in dev.sms}
    pd_sms = [PdSm(n, n in outputs,
                   pd_sm_config(sms[n].start_address or 0, bits, sms[n].control_byte or 0),
                   sms[n].op_only)
              for n, bits in sorted(out + inp)]
    return SlaveSetup(
        position=slave.position, phys_addr=slave.phys_addr, vendor_id=dev.vendor.id or 0,
        product_code=dev.product_code or 0, alias=slave.cfg.alias,
        mailbox=((mailbox[0].number, SmConfig(mailbox[0].start_address or 0,
                                              mailbox[0].mailbox_size,
                                              mailbox[0].mailbox_control, True)),
                 (mailbox[1].number, SmConfig(mailbox[1].start_address or 0,
                                              mailbox[1].mailbox_size,
                                              mailbox[1].mailbox_control, True)))
        if len(mailbox) >= 2 else None,
        bootstrap=bootstrap, pd_sms=pd_sms, fmmus=list(lay.fmmus), dc=dc,
        assign_activate=assign_activate, device_emulation=dev.device_emulation,
        preop_timeout=(info and info.preop_timeout) or 0,
        safeop_op_timeout=(info and info.safeop_op_timeout) or 0,
        back_to_init_timeout=(info and info.back_to_init_timeout) or 0,
        back_to_safeop_timeout=(info and info.back_to_safeop_timeout) or 0,
        watchdog=slave.watchdog)
