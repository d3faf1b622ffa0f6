"""Running a simulation: the fixed-step driver and the frames it records (:mod:`.driver`), error-controlled
adaptive steps (:mod:`.adaptive`), the run options declared once (:mod:`.options`), progress and set-up logging
(:mod:`.progress`), and the energy bound that stops a blow-up (:mod:`.energy`).

Nothing is imported here, so that the lower layers can use :mod:`.progress` (set-up timing) and the scene loader
:mod:`.options` without loading the drivers.
"""
