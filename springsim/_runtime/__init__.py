"""The process around the numerics (private): compiled kernels and their cache (:mod:`.accel`), the command line's
allocator policy (:mod:`.alloc`), the memory available to an allocation (:mod:`.memory`), one BLAS thread inside a
solve (:mod:`.threads`).

Nothing is imported here: ``springsim/__init__.py`` imports :mod:`.accel` itself, and the other modules are imported
where they are used.
"""
