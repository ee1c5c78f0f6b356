"""Writers for lint results, one module per output format (text, json, junit, sarif).

Each module has ``write(results, rules, out)``: ``results`` is the list of
:class:`~ecatcfg.esi.lint.finding.FileResult`, ``rules`` the rules in effect by id.
"""

FORMATS = ("text", "json", "junit", "sarif")
