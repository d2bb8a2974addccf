"""Ground perception: stereo from the downlinked frames (Drake-free; OpenCV)."""
