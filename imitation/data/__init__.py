"""Episodes, spaces, the MCAP demo store, loaders and the recorder."""
