// A PLY file checked before assimp reads it (core/robot internal).
#pragma once

#include <string_view>

#include "arref/base/status.h"

namespace arref {

// Assimp 5.2's PLY reader never returns on some malformed headers and, on some malformed bodies,
// allocates until the process dies (both found by tests/fuzz/mesh_fuzz.cpp). So the header is
// checked ("ply", one format line, elements each with properties of known types, end_header)
// and so is the body: every element's rows as the header declares them, each value a number
// its type can hold, each list no longer than the file. An IO_ERROR names the first fault.
// `bytes` is the whole file, read once: assimp then reads the same bytes from memory.
Status CheckPly(std::string_view bytes);

}  // namespace arref
