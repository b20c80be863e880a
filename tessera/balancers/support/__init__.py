"""What the balancing techniques share and none of them is: the load field and where it comes from
(``load``), the predicted load (``predictor``), strips→tiles edges (``strips``), the load-weight table
(``table``) and the binary split tree (``tree``)."""
