"""The rules by which a slave refuses a state, named once for both ends of the wire.

An AL status code (0x0134, ETG.1000.6 Table 11) says which check a slave's firmware failed;
the rule says which value made it fail.  The emulated firmware (``runtime/segment/
al_checks.py``) refuses by exactly one of these rules and keeps it with the code; the
master's diagnosis (``runtime/master/diagnose.py``) finds the rules it can see from what it
reads over the wire (registers, the SII, CoE objects) and names them in words.  Neither side
imports the other: they share this vocabulary, and the agreement test
(``tests/test_diagnosis_agreement.py``) checks that the rule the emulator applied is one the
diagnosis names (``docs/diagnostics.md`` "Refusal rules").
"""

from __future__ import annotations

from enum import Enum

from ecatcfg.record import record


class Rule(Enum):
    """One check a slave makes before it enters a state; the value is its stable name (JSON
    ``rules`` of a cause), :attr:`words` what it checks."""

    # INIT->PREOP / INIT->BOOT (0x0016 / 0x0015; SOES ESC_checkmbx)
    MAILBOX_SM = "mailbox-sm"
    BOOTSTRAP_SM = "bootstrap-sm"
    # PREOP->SAFEOP, SAFEOP->OP (0x001D outputs / 0x001E inputs; SOES ESC_checkSM23)
    SM_LENGTH = "sm-length"
    SM_DISABLED = "sm-disabled"
    SM_START = "sm-start"
    SM_CONTROL = "sm-control"
    NO_FMMU = "no-fmmu"
    NO_ASSIGNMENT = "no-assignment"
    PDO_MISSING = "pdo-missing"
    ENTRY_MISSING = "entry-missing"
    ENTRY_NOT_MAPPABLE = "entry-not-mappable"
    # PREOP->SAFEOP with SYNC0 (0x0035)
    SYNC0_NO_CYCLE = "sync0-no-cycle"
    SYNC0_BELOW_MINIMUM = "sync0-below-minimum"
    # PREOP->SAFEOP of an SoE drive (0x0045)
    SOE_IDNS = "soe-idns"
    # any transition: the state machine itself (0x0011, 0x0012, 0x0013)
    STATE_CHANGE = "state-change"
    UNKNOWN_STATE = "unknown-state"
    BOOT_UNSUPPORTED = "boot-unsupported"
    # SAFEOP/OP: outputs stopped (0x001B)
    SM_WATCHDOG = "sm-watchdog"
    # a refusal asked for by a test (EmulatedSlave.refuse): no rule of the firmware
    INJECTED = "injected"

    @property
    def words(self) -> str:
        return _WORDS[self]


_WORDS = {
    Rule.MAILBOX_SM: "SM0/SM1 must be the slave's mailbox: start, length, mode and "
                     "direction as its SII gives them, enabled",
    Rule.BOOTSTRAP_SM: "SM0/SM1 must be the slave's bootstrap mailbox (SII words 0x14-0x17)",
    Rule.SM_LENGTH: "a process-data SM's length must be the bytes its assigned PDOs map",
    Rule.SM_DISABLED: "a process-data SM whose PDOs map data must be enabled",
    Rule.SM_START: "a process-data SM must start where the slave's SII places it",
    Rule.SM_CONTROL: "a process-data SM's mode and direction must be the SII's",
    Rule.NO_FMMU: "an FMMU of the SM's direction must cover the whole SM",
    Rule.NO_ASSIGNMENT: "the SM's PDO assignment object (0x1C10 + n) must exist",
    Rule.PDO_MISSING: "every assigned PDO must be a mapping object the slave has",
    Rule.ENTRY_MISSING: "every mapped entry must be an object and subindex the slave has",
    Rule.ENTRY_NOT_MAPPABLE: "every mapped entry must be mappable in the SM's direction "
                             "(PdoMapping R for outputs, T for inputs)",
    Rule.SYNC0_NO_CYCLE: "SYNC0 on needs a SYNC0 cycle time (0x09A0)",
    Rule.SYNC0_BELOW_MINIMUM: "the SYNC0 cycle must not be shorter than the slave's minimum "
                              "cycle time (0x1C32:05 / 0x1C33:05)",
    Rule.SOE_IDNS: "an SoE drive needs every IDN of its S-0-0018 written before SAFEOP",
    Rule.STATE_CHANGE: "the state requested must be reachable from the current one",
    Rule.UNKNOWN_STATE: "the state requested must be a state",
    Rule.BOOT_UNSUPPORTED: "BOOT needs a bootstrap mailbox and a boot loader",
    Rule.SM_WATCHDOG: "outputs must arrive within the SM watchdog time",
    Rule.INJECTED: "a refusal injected by a test",
}


@record
class Refusal:
    """A state change the emulated firmware refused: its AL status code, the rule, and
    the values that broke it (``detail``, in words)."""

    code: int
    rule: Rule
    detail: str = ""
