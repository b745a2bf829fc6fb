"""The uncertainty of an answer and the checks of the data around a fit: the Cramér–Rao bound and experiment
design, the encoder's bootstrap, validation, corrupted samples and outliers, an input logged late."""
