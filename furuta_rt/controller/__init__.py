"""Control design, observer, friction compensation and the real-time `update` (Controller)."""
