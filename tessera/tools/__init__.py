"""What users do with a model on screen (issue 35): clip planes and section boxes
(:mod:`tessera.tools.clipping`), picking (:mod:`tessera.tools.picking`). Pure: numpy only."""
