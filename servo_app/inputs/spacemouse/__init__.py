"""3Dconnexion SpaceMouse: HID report parsing, the drain-to-newest reader, shaping, spacenavd client."""
