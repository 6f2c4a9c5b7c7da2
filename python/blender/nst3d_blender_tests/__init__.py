"""The Blender add-on's tests, run by ../test_addon.py in Blender."""
