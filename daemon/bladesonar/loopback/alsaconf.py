"""A private ALSA configuration for the loopback room: two PCMs on two FIFOs.

``bladesonar_play`` records whatever the daemon plays into ``fifo_play`` (file plugin over a
null slave); ``bladesonar_cap`` feeds the daemon's capture from ``fifo_cap`` (``infile``).
Neither plugin paces in real time and neither needs a sound card. The file is added to the
system configuration through ``ALSA_CONFIG_PATH`` (given alone it would replace it, so the
slaves are written inline).
"""

from __future__ import annotations

from pathlib import Path

PLAY_PCM = "bladesonar_play"
CAP_PCM = "bladesonar_cap"
SYSTEM_CONF = "/usr/share/alsa/alsa.conf"


def _quote(path: Path | str) -> str:
    s = str(path)
    if '"' in s or "\\" in s:
        raise ValueError(f"{s!r}: an ALSA config path must not contain quotes or backslashes")
    return f'"{s}"'


def alsa_conf_text(fifo_play: Path | str, fifo_cap: Path | str, *, play_pcm: str = PLAY_PCM,
                   cap_pcm: str = CAP_PCM) -> str:
    return (
        "# written by bladesonar room: the loopback self-test's private PCMs\n"
        f"pcm.{play_pcm} {{\n    type file\n    file {_quote(fifo_play)}\n    format raw\n"
        "    slave.pcm { type null }\n}\n"
        f"pcm.{cap_pcm} {{\n    type file\n    file \"/dev/null\"\n    infile {_quote(fifo_cap)}\n"
        "    slave.pcm { type null }\n}\n")


def write_alsa_config(path: Path | str, fifo_play: Path | str, fifo_cap: Path | str, *,
                      play_pcm: str = PLAY_PCM, cap_pcm: str = CAP_PCM) -> dict[str, str]:
    """Write the config file; return the environment a process needs to see the PCMs."""
    p = Path(path)
    p.write_text(alsa_conf_text(fifo_play, fifo_cap, play_pcm=play_pcm, cap_pcm=cap_pcm),
                 encoding="utf-8")
    return alsa_env(p)


def alsa_env(conf: Path | str) -> dict[str, str]:
    """``ALSA_CONFIG_PATH`` that adds ``conf`` to the system configuration."""
    return {"ALSA_CONFIG_PATH": f"{SYSTEM_CONF}:{Path(conf).resolve()}"}
