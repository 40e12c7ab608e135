"""Export to CG tools: mesh files in the model's vertex order (``geometry.obj_io``), a
rigged, animatable glTF 2.0 of one person (:mod:`.rig`, :mod:`.gltf`; hair, brows, lashes
and beards as alpha-textured cards: :mod:`.hair_cards`), a reference glTF
evaluator to check it against the model (:mod:`.reference`) and a local three.js viewer
(:mod:`.viewer`). The CLI (:mod:`.cli`) adds `hack-render export` and `hack-render view`."""
