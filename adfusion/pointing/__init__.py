"""Night pointing after Bleif (DLR-TUBSAT, tubsat.md §6–§9): star angles and body-axis
slews (:mod:`.slews`), command bookkeeping (:mod:`.commands`), pass planning with SGP4
(:mod:`.passplan`) and the drift budget of a star fix (:mod:`.drift`)."""
