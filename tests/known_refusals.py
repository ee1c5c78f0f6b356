"""Sweep cases of real files that fail today for a reason we know, each named with its reason
and the work that removes it.

The corpus sweeps glob every file of both corpora, so a new real file becomes a case the day
it arrives.  Where such a case fails for a reason that is understood but not yet fixed, it is
listed here instead of being skipped: the case still runs, and ``conftest.py`` requires it to
fail *with the failure written here* (a regular expression searched in the failure's text).
It then counts as an expected failure (``xfailed``, with the reason).  Any other failure of a
listed case fails the run, and so does a listed case that passes: the entry must then be
taken out, in the commit that makes it pass.  Nothing here hides a new kind of failure.

Keys are pytest node ids (``tests/FILE.py::TEST[PARAMS]``); the work that removes an entry is
named in words.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Known:
    failure: str       # regular expression searched in the failure's text
    reason: str        # why it fails today, in words
    until: str         # the work that removes the entry


# The work that removes entries, named once.
FIRST_CONTACT = "first contact with the exporters' whole vocabulary and these files' shapes"
CAPTURES = "every capture of both corpora replayed and its devices' timing fitted"


KNOWN: dict[str, Known] = {
    # -- captures --------------------------------------------------------------------------
    "tests/test_conformance.py::test_every_capture_is_listed":
        Known(r"assert \{.*\} == \{", "the captures added to corpus-extra/pcap (EtherCrab: an "
              "EL6910 TwinSAFE bring-up, SDO reads answered with abort codes) have no "
              "recorded conformance figures yet", CAPTURES),
    "tests/test_dc_unit.py::test_the_rule_classifies_the_real_slaves_as_their_replies_show":
        Known(r"assert \{.*\} == \{", "the new captures bring slaves the DC-unit table does "
              "not list yet", CAPTURES),
    **{f"tests/test_timing_fit.py::{t}":
       Known(r"replay-mailbox-el6910|assert|Counter", "the new captures' windows (EL6910 "
             "EEPROM reads, SDO downloads) are not in the timing tables yet", CAPTURES)
       for t in ("test_every_window_of_a_device_with_an_esi_holds_the_table",
                 "test_no_figure_keeps_more_windows_in_step_than_the_tables",
                 "test_the_captured_devices_and_their_kinds", "test_what_stays_out_of_step")},
}
