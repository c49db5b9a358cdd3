"""The HDF5 artifacts that stages exchange: `h5` holds the atomic writer, provenance attrs and checked reads;
each other module is the one typed reader/writer of one artifact, where its dataset names are defined."""
