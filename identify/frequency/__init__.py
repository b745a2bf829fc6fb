"""The frequency view: the measured frequency response, the best linear approximation, and a structure's
parameters fitted from a frequency response."""
