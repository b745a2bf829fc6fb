"""The estimators: each module one family's fit of a recording (regression, output error, instrumental
variables, friction, prediction error, the generic fit of a linear structure, ...), their numerical kernels and
the batch engine's.  ``identify.fit(rec, method)`` reaches them by name (``identify.methods``)."""
