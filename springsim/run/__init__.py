"""Running a simulation: the fixed-step driver and the frames it records (:mod:`.driver`), error-controlled
adaptive steps (:mod:`.adaptive`), the run options declared once (:mod:`.options`), and the energy bound that stops
a blow-up (:mod:`.energy`), and interrupts that stop every process of a distributed run at the same step
(:mod:`.interrupts`). Progress and set-up logging, which every layer uses, is :mod:`springsim.progress`.

Nothing is imported here, so that the scene loader can use :mod:`.options` without loading the drivers.
"""
