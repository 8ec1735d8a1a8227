"""`armbridge draw`: text, SVG, CSV points, images and shapes turned into a joint-space plan
for the 3R drawing arm (see docs/drawing.md)."""
