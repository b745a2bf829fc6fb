"""The default estimator's selection (``identify.fit`` with no method): the candidates compared by the evidence,
the part checks, the structures fitted on evidence, recordings made in a loop, and the record of the choice."""
