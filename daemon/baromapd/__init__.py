"""baromapd: the acquisition daemon (ports, device sessions, recorder, Zenoh, systemd)."""
