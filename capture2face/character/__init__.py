"""Any character, ready to drive: loaded (:mod:`.load`: the built-in avatars, a FaceRig .npz,
a user's .glb with its mapping JSON), its tracker landmarks found on its mesh
(:mod:`.landmarks`) and its automatic wrinkles (:mod:`.auto_wrinkles`)."""
