#pragma once
// Text helpers shared by the mesh readers (ply_off.cpp, obj.cpp, gltf.cpp), which all read
// untrusted files and put pieces of them into error messages.

#include <cstddef>
#include <string>
#include <string_view>

namespace proxima::detail {

// Text from a file as it may appear in a message: garbage input must not put control bytes or
// megabytes into a status that ends up in logs and gRPC replies. Bytes outside printable ASCII
// become \xNN; more than `limit` bytes end in "...".
std::string printable(std::string_view text, std::size_t limit = 40);

// The whole token as a double (a leading '+' allowed, as C and Python write it). "nan" and "inf"
// are accepted on purpose: validate_mesh then rejects them with the vertex index, the more useful
// message. Out-of-range values give the nearest double (0 or an infinity).
bool parse_double(std::string_view token, double& out);

}  // namespace proxima::detail
