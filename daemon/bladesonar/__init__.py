"""bladesonar: rotation direction and rate of a fan from a pulsed sonar's multipath echoes.

Method: M. Robinson, "Multipath-dominant, pulsed doppler analysis of rotating blades".
Pure computation lives in the top-level modules (waveform, sim, dsp); devices, MQTT,
files and systemd live at the edges (io, service) and are thin.
"""

__version__ = "0.2.0.dev0"
