# The ROS 2 message layer: definitions, the type registry, CDR and CBOR codecs, converters.
