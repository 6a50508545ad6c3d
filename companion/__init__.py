"""fpv-station's companion side: what talks to the vehicle and its cameras (runs on the Pi)."""
