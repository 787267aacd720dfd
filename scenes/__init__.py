"""Built-in scenes (TOML) and the procedural anatomy they reference."""
