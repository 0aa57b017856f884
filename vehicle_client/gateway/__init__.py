"""Gateway mode: local units behind one upstream link, and their topics."""
