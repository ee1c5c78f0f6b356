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

BEREMIZ_HIGEN = "corpus-extra/beremiz-tests/wago_higen/config.xml"
BEREMIZ_SANYO = "corpus-extra/beremiz-tests/wago_sanyo/config.xml"
SOEM_SAMPLE = "corpus-extra/soem-sample/sample-eni.xml"

_BEREMIZ = ("Beremiz's EtherLab-plugin file is a partial ENI: mailbox SMs of length 0 and "
            "CoE writes in INIT->INIT (II), which no slave can take (no mailbox in INIT)")
# SOEM's report (a dict that starts with 'found') when it did not reach OP, or a count of
# slaves or sizes that differs; pytest words the comparison "assert 5 == 4" or, from 9.2 on,
# "assert (5 == 4)", and shortens long dicts: only the start is matched.
_SOEM_NOT_OP = r"\{'found': \d+|assert \(?\d+ == \d+\)?"
_SOEM_SAMPLE = ("SOEM's hand-written sample gives its slaves a mailbox but no station "
                "address; the reader takes a slave without PhysAddr/AutoIncAddr as passive")

KNOWN: dict[str, Known] = {
    # -- the ENI reader and check --------------------------------------------------------
    f"tests/test_eni_io.py::test_every_corpus_eni_reads_with_matching_counts[{BEREMIZ_HIGEN}]":
        Known(r"wago_higen/config\.xml", _BEREMIZ + "; the reader leaves the 3 II writes out "
              "as refused", FIRST_CONTACT),
    f"tests/test_eni_io.py::test_every_corpus_eni_reads_with_matching_counts[{SOEM_SAMPLE}]":
        Known(r"'Sample device A' has no <PhysAddr> and <AutoIncAddr>", _SOEM_SAMPLE,
              FIRST_CONTACT),
    f"tests/test_check.py::test_corpus_enis_have_no_error_but_the_named_defects[{BEREMIZ_HIGEN}]":
        Known(r"ENI501 slave 'EDA7000 CoE Drive': Mailbox/Send: length 0", _BEREMIZ,
              FIRST_CONTACT),
    f"tests/test_check.py::test_corpus_enis_have_no_error_but_the_named_defects[{SOEM_SAMPLE}]":
        Known(r"ENI004 slave 'Sample device A' has no <PhysAddr>", _SOEM_SAMPLE, FIRST_CONTACT),
    "tests/test_contents_schema.py::test_what_exporters_write_beyond_the_schema_is_listed":
        Known(r"sample-eni\.xml:19: slave 'Sample device A' has no <PhysAddr>", _SOEM_SAMPLE,
              FIRST_CONTACT),

    # -- apply --virtual, with and without ESI ---------------------------------------------
    **{f"tests/test_eni_only.py::test_corpus_eni_reaches_op_and_cycles[{BEREMIZ_HIGEN}-{w}]":
       Known(r"wago_higen/config\.xml: the ENI asks for 3 things apply does not do",
             _BEREMIZ, FIRST_CONTACT) for w in ("eni-only", "with-esi")},
    f"tests/test_eni_only.py::test_corpus_eni_reaches_op_and_cycles[{BEREMIZ_SANYO}-with-esi]":
        Known(r"'SanyoDenki RS2 EtherCAT' \[check device state for PREOP\]: slave stays in "
              r"INIT\+ERR, AL status code 0x0016", "Beremiz's partial ENI gives the drive "
              "mailbox SMs of length 0; the drive emulated from its ESI refuses PREOP with "
              "0x0016 (invalid mailbox configuration) as a real one would", FIRST_CONTACT),
    **{f"tests/test_eni_only.py::test_corpus_eni_reaches_op_and_cycles[{SOEM_SAMPLE}-{w}]":
       Known(r"'Sample device A' has no <PhysAddr> and <AutoIncAddr>", _SOEM_SAMPLE,
             FIRST_CONTACT) for w in ("eni-only", "with-esi")},
    "tests/test_eni_only.py::test_corpus_eni_reaches_op_and_cycles"
    "[corpus-extra/pmec-fostwin/FOSTWIN-Primary1.xml-with-esi]":
        Known(r"'Term 2 \(EL6695\)' \[download pdo 0x1A04 entries\]: SDO abort 0x06020000",
              "the EL6695 bridge emulated from its ESI (corpus-extra esi/dls EL66xx) has no "
              "0x1A04 for TwinCAT's mapping of the bridge's process data", FIRST_CONTACT),
    # -- SOEM on `simulate --eni` over veth --------------------------------------------------
    f"tests/test_eni_only.py::test_soem_reaches_op_on_an_eni_without_esi[{BEREMIZ_HIGEN}]":
        Known(_SOEM_NOT_OP, _BEREMIZ + "; the emulated drive refuses PREOP with 0x0016",
              FIRST_CONTACT),
    f"tests/test_eni_only.py::test_soem_reaches_op_on_an_eni_without_esi[{BEREMIZ_SANYO}]":
        Known(r"assert \(?-1 == 0\)?", _BEREMIZ, FIRST_CONTACT),
    f"tests/test_eni_only.py::test_soem_reaches_op_on_an_eni_without_esi[{SOEM_SAMPLE}]":
        Known(r"'Sample device A' has no <PhysAddr> and <AutoIncAddr>", _SOEM_SAMPLE,
              FIRST_CONTACT),
    **{"tests/test_eni_only.py::test_soem_reaches_op_on_an_eni_without_esi"
       f"[corpus-extra/pmec-fostwin/{f}]":
       Known(r"\(0, 2\)\] == \[.*\(160, 162\)\]", "SOEM's process-data sizes of the EL6695 "
             "bridge emulated from the ENI differ from the ENI's (162 bytes in TwinCAT's "
             "image, 2 bytes by SOEM's own mapping)", FIRST_CONTACT)
       for f in ("FOSTWIN-Primary1.xml", "FOSTWIN_Secondary1.xml")},
    **{"tests/test_eni_only.py::test_soem_reaches_op_on_an_eni_without_esi"
       f"[corpus-extra/{f}]":
       Known(_SOEM_NOT_OP, "SOEM does not reach OP, or maps other sizes, on "
             "these TwinCAT exports emulated from the ENI alone (EL6001/EL6090 serial and "
             "display terminals, EasyCAT, HBM GEN DAQ with 113 TxPDOs)", FIRST_CONTACT)
       for f in ("pmec-foswec2/FOSWEC2_MD_20230314.xml", "pmec-foswec2/NAVFACOSWECSxml.xml",
                 "pmec-lupa/LUPA1kHz_DC.xml", "pmec-wec-bench/Pendulum2XML.xml")},

}
