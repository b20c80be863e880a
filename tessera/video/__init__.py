"""Video to the browser (issue 21): the encoder's source picture and the link's rate control, pure."""
