"""The Arduino sketch (``motorid_bench/``) and the generator of its sine table."""
