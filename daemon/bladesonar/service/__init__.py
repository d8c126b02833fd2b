"""The daemon's edges: audio devices, MQTT, systemd, logging, and the loop that joins them."""
