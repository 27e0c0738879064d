"""Pictures of towns and camera frames for people to look at."""
