"""motorsim: the simulated bench (plant, excitations, encoder, recordings, rigs)."""
from .excitation import (
    DUTY_LIMIT,
    PRBS,
    Chirp,
    Constant,
    Excitation,
    Multisine,
    OddMultisine,
    Sine,
    Step,
    parse_excitation,
)
from .plant import Motor, Plant, Trajectory, simulate
from .reading import read_recording
from .recording import Recording, RecordingFormatError
from .rig import Experiment, Rig, SimRig
from .sensors import DEFAULT_COUNTS_PER_REV, Encoder, backward_difference, counts_to_angle
from .writing import RecordingWriter, write_recording

__all__ = [
    "DUTY_LIMIT", "PRBS", "Chirp", "Constant", "Excitation", "Multisine", "OddMultisine", "Sine", "Step",
    "parse_excitation", "Motor", "Plant", "Trajectory", "simulate", "Recording", "RecordingFormatError",
    "read_recording", "write_recording", "RecordingWriter", "Experiment", "Rig", "SimRig", "DEFAULT_COUNTS_PER_REV",
    "Encoder", "backward_difference", "counts_to_angle",
]
