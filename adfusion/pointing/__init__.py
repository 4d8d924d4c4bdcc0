"""Night pointing after Bleif (DLR-TUBSAT; docs/references.md#bleif-2004): star angles and
body-axis slews (:mod:`.slews`), command bookkeeping (:mod:`.commands`), pass planning with SGP4
(:mod:`.passplan`) and the drift budget of a star fix (:mod:`.drift`)."""
