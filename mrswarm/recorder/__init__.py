"""The flight recorder: every message of a swarm into MCAP, its exports, replay and live views (docs/recording.md)."""
