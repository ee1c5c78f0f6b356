"""SOEM's timeouts widened for a busy test host, set once for every probe that runs pysoem.

SOEM waits a fixed time for each reply: ``EC_TIMEOUTRET`` (2 ms) for a datagram, 20 ms for an
SII word or a mailbox write, 2 s for a state change (SOEM's ``ethercattype.h``; pysoem makes
them settable as ``pysoem.settings.timeouts``, in microseconds).  A real slave answers in
microseconds; the virtual segment answering over veth is a Python process on a 2-core machine
that other jobs share, and a reply it sends 3 ms late makes SOEM report a slave missing or a
state not reached: a test failure that says nothing about the configuration under test.

The probes ask SOEM whether it can configure and run what we emulate, not how fast: each
timeout is widened by a factor that leaves a host tens of milliseconds of stall (a lost frame
still ends as lost, only later).  SOEM's own logic is unchanged: it resends on its ``ret``
period within the longer ``safe`` window as it always does.
"""

from __future__ import annotations

from typing import Any

# microseconds; SOEM's defaults in the comment
TIMEOUTS_US = {
    "ret": 100_000,           # 2 000: one datagram's reply
    "safe": 500_000,          # 20 000: a datagram resent until this
    "eeprom": 500_000,        # 20 000: one SII word
    "tx_mailbox": 500_000,    # 20 000: room in the slave's write mailbox
    "rx_mailbox": 5_000_000,  # 700 000: a mailbox reply
    "state": 10_000_000,      # 2 000 000: a state change
}


def be_patient(pysoem: Any) -> None:
    """Set SOEM's timeouts (process-wide) to :data:`TIMEOUTS_US`."""
    for name, us in TIMEOUTS_US.items():
        setattr(pysoem.settings.timeouts, name, us)
