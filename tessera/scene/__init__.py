"""The scene model both sides share: glTF containers, the object graph, animations, a frame's
scene state and the coordinator's timeline of it."""
