"""Wire codec, links, master and virtual segment.

Empty until the runtime issues land.  Nothing here may be imported by ``ecatcfg --help``
or ``ecatcfg devices`` (scapy alone costs 1.7 s to import).
"""
