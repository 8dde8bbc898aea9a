"""Motion Marionette: rigid motion transfer from a monocular video onto a single image."""
