"""The ``adfusion`` sub-commands, one module each (``cmd_<name>(args) -> exit code``), and
:mod:`.args`, the argument types and checks they share. :mod:`adfusion.app.cli` builds the
parser and dispatches to them; heavy imports stay inside the commands so that ``adfusion
--help`` is instant.
"""
