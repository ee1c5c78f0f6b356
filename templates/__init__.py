"""jinja2 templates for generated text, read through importlib.resources.

This ``__init__.py`` is what lets ``importlib.resources.files("ecatcfg.templates")`` find
the folder in an installed wheel on Python 3.11.
"""
