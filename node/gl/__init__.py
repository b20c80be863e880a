"""GL: the one context factory (headless EGL) and the retained-mode tile renderer."""
