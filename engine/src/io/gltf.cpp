#include "io/gltf.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <limits>
#include <map>
#include <optional>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "io/text.hpp"

namespace proxima::detail {

namespace {

using Json = nlohmann::json;

constexpr std::uint32_t GLB_MAGIC = 0x46546C67;   // "glTF"
constexpr std::uint32_t CHUNK_JSON = 0x4E4F534A;  // "JSON"
constexpr std::uint32_t CHUNK_BIN = 0x004E4942;   // "BIN\0"
constexpr std::uint64_t GLB_HEADER = 12;
constexpr std::uint64_t CHUNK_HEADER = 8;

// Indices are 32-bit in TriangleMesh.
constexpr std::uint64_t MAX_VERTICES = std::numeric_limits<std::uint32_t>::max();
// The output a file may produce (vertices, and separately triangles): instancing lets a few
// bytes of JSON repeat a large mesh, so the output is bounded by the input's size.
constexpr std::uint64_t MIN_OUTPUT_LIMIT = std::uint64_t{1} << 20;
constexpr std::uint64_t OUTPUT_PER_INPUT_BYTE = 16;

constexpr std::uint32_t BYTE = 5120;
constexpr std::uint32_t UNSIGNED_BYTE = 5121;
constexpr std::uint32_t SHORT = 5122;
constexpr std::uint32_t UNSIGNED_SHORT = 5123;
constexpr std::uint32_t UNSIGNED_INT = 5125;
constexpr std::uint32_t FLOAT = 5126;

constexpr std::uint64_t TRIANGLES = 4;
constexpr std::uint64_t TRIANGLE_STRIP = 5;
constexpr std::uint64_t TRIANGLE_FAN = 6;

// Required extensions that change nothing this reader reads (materials, textures, lights), and
// KHR_mesh_quantization, which it implements. Every other required extension is refused.
bool is_supported_required_extension(std::string_view name) {
    constexpr std::array<std::string_view, 6> KNOWN = {
        "KHR_mesh_quantization", "KHR_texture_transform", "KHR_texture_basisu",
        "EXT_texture_webp",      "EXT_texture_avif",      "KHR_lights_punctual"};
    return std::find(KNOWN.begin(), KNOWN.end(), name) != KNOWN.end() ||
           name.starts_with("KHR_materials_");
}

// A JSON value as a message shows it: scalars as written, containers by their type.
std::string describe(const Json& value) {
    if (value.is_object() || value.is_array()) {
        return "an " + std::string(value.type_name());
    }
    return printable(value.dump(-1, ' ', false, Json::error_handler_t::replace));
}

std::string hex32(std::uint32_t value) {
    std::array<char, 16> buf{};
    std::snprintf(buf.data(), buf.size(), "0x%08x", static_cast<unsigned>(value));
    return buf.data();
}

std::uint32_t little_u32(std::string_view data, std::uint64_t at) {
    std::uint32_t v = 0;
    for (int b = 3; b >= 0; --b) {
        v = (v << 8) | static_cast<unsigned char>(
                           data[static_cast<std::size_t>(at) + static_cast<std::size_t>(b)]);
    }
    return v;
}

// The offset of the first byte that is not part of well-formed UTF-8, or npos.
std::size_t invalid_utf8_at(std::string_view text) {
    std::size_t i = 0;
    const auto byte = [&](std::size_t k) { return static_cast<unsigned char>(text[k]); };
    while (i < text.size()) {
        const unsigned char c = byte(i);
        std::size_t extra = 0;
        unsigned char low = 0x80;
        unsigned char high = 0xbf;
        if (c < 0x80) {
            ++i;
            continue;
        }
        if (c >= 0xc2 && c <= 0xdf) {
            extra = 1;
        } else if (c >= 0xe0 && c <= 0xef) {
            extra = 2;
            low = c == 0xe0 ? 0xa0 : 0x80;
            high = c == 0xed ? 0x9f : 0xbf;
        } else if (c >= 0xf0 && c <= 0xf4) {
            extra = 3;
            low = c == 0xf0 ? 0x90 : 0x80;
            high = c == 0xf4 ? 0x8f : 0xbf;
        } else {
            return i;
        }
        if (text.size() - i - 1 < extra) {
            return i;
        }
        for (std::size_t k = 1; k <= extra; ++k) {
            const unsigned char next = byte(i + k);
            if (next < (k == 1 ? low : 0x80) || next > (k == 1 ? high : 0xbf)) {
                return i;
            }
        }
        i += extra + 1;
    }
    return std::string_view::npos;
}

// Records why a document does not parse, without exceptions.
class ErrorOnlySax : public nlohmann::json_sax<Json> {
  public:
    bool null() override { return true; }
    bool boolean(bool) override { return true; }
    bool number_integer(number_integer_t) override { return true; }
    bool number_unsigned(number_unsigned_t) override { return true; }
    bool number_float(number_float_t, const string_t&) override { return true; }
    bool string(string_t&) override { return true; }
    bool binary(binary_t&) override { return true; }
    bool start_object(std::size_t) override { return true; }
    bool key(string_t&) override { return true; }
    bool end_object() override { return true; }
    bool start_array(std::size_t) override { return true; }
    bool end_array() override { return true; }
    bool parse_error(std::size_t, const std::string&,
                     const nlohmann::detail::exception& ex) override {
        std::string what = ex.what();
        // "[json.exception.parse_error.101] parse error at line 1, column 2: ..."
        if (const auto close = what.find("] "); close != std::string::npos) {
            what.erase(0, close + 2);
        }
        message = what;
        return false;
    }

    std::string message;
};

// Strict base64 (RFC 4648, standard alphabet): padding only at the end, no whitespace, no
// leftover bits. Returns the problem, or an empty string.
std::string decode_base64(std::string_view text, std::string& out) {
    const auto value = [](char c) -> int {
        if (c >= 'A' && c <= 'Z') {
            return c - 'A';
        }
        if (c >= 'a' && c <= 'z') {
            return c - 'a' + 26;
        }
        if (c >= '0' && c <= '9') {
            return c - '0' + 52;
        }
        if (c == '+') {
            return 62;
        }
        if (c == '/') {
            return 63;
        }
        return -1;
    };
    std::size_t padding = 0;
    while (padding < 2 && padding < text.size() && text[text.size() - 1 - padding] == '=') {
        ++padding;
    }
    if (padding > 0 && text.size() % 4 != 0) {
        return "'=' padding in a length that is not a multiple of 4";
    }
    const std::string_view digits = text.substr(0, text.size() - padding);
    if (digits.size() % 4 == 1) {
        return "its length leaves a single character in the last group";
    }
    out.clear();
    out.reserve(digits.size() / 4 * 3 + 2);
    std::uint32_t bits = 0;
    int held = 0;
    for (std::size_t i = 0; i < digits.size(); ++i) {
        const int v = value(digits[i]);
        if (v < 0) {
            return "character '" + printable(digits.substr(i, 1)) + "' at offset " +
                   std::to_string(i) + " is not base64";
        }
        bits = (bits << 6) | static_cast<std::uint32_t>(v);
        held += 6;
        if (held >= 8) {
            held -= 8;
            out += static_cast<char>((bits >> held) & 0xff);
        }
    }
    if ((bits & ((1u << held) - 1u)) != 0) {
        return "the last character has bits set beyond the data";
    }
    return {};
}

// %XX escapes decoded. Returns the problem, or an empty string.
std::string percent_decode(std::string_view text, std::string& out) {
    const auto hex = [](char c) -> int {
        if (c >= '0' && c <= '9') {
            return c - '0';
        }
        if (c >= 'a' && c <= 'f') {
            return c - 'a' + 10;
        }
        if (c >= 'A' && c <= 'F') {
            return c - 'A' + 10;
        }
        return -1;
    };
    out.clear();
    for (std::size_t i = 0; i < text.size(); ++i) {
        if (text[i] != '%') {
            out += text[i];
            continue;
        }
        const int high = i + 2 < text.size() ? hex(text[i + 1]) : -1;
        const int low = i + 2 < text.size() ? hex(text[i + 2]) : -1;
        if (high < 0 || low < 0) {
            return "'%' at offset " + std::to_string(i) + " is not followed by two hex digits";
        }
        out += static_cast<char>(high * 16 + low);
        i += 2;
    }
    if (out.find('\0') != std::string::npos) {
        return "it contains a NUL byte";
    }
    return {};
}

// A JSON number that is a non-negative integer (written 3 or 3.0).
bool to_uint(const Json& v, std::uint64_t& out) {
    if (v.is_number_unsigned()) {
        out = v.get<std::uint64_t>();
        return true;
    }
    if (v.is_number_integer()) {
        const auto i = v.get<std::int64_t>();
        if (i < 0) {
            return false;
        }
        out = static_cast<std::uint64_t>(i);
        return true;
    }
    if (v.is_number_float()) {
        const double d = v.get<double>();
        if (d >= 0.0 && d <= 9007199254740992.0 && d == std::floor(d)) {
            out = static_cast<std::uint64_t>(d);
            return true;
        }
    }
    return false;
}

const Json* find(const Json& object, const char* key) {
    const auto it = object.find(key);
    return it == object.end() ? nullptr : &*it;
}

// a + b and a * b, false on overflow.
bool add(std::uint64_t a, std::uint64_t b, std::uint64_t& out) {
    if (a > std::numeric_limits<std::uint64_t>::max() - b) {
        return false;
    }
    out = a + b;
    return true;
}
bool mul(std::uint64_t a, std::uint64_t b, std::uint64_t& out) {
    if (a != 0 && b > std::numeric_limits<std::uint64_t>::max() / a) {
        return false;
    }
    out = a * b;
    return true;
}

std::uint64_t component_size(std::uint32_t type) {
    switch (type) {
        case BYTE:
        case UNSIGNED_BYTE:
            return 1;
        case SHORT:
        case UNSIGNED_SHORT:
            return 2;
        case UNSIGNED_INT:
        case FLOAT:
            return 4;
        default:
            return 0;
    }
}

std::string component_name(std::uint32_t type) {
    switch (type) {
        case BYTE:
            return "BYTE (5120)";
        case UNSIGNED_BYTE:
            return "UNSIGNED_BYTE (5121)";
        case SHORT:
            return "SHORT (5122)";
        case UNSIGNED_SHORT:
            return "UNSIGNED_SHORT (5123)";
        case UNSIGNED_INT:
            return "UNSIGNED_INT (5125)";
        case FLOAT:
            return "FLOAT (5126)";
        default:
            return std::to_string(type);
    }
}

// Components per element of an accessor type; 0 for an unknown type.
std::uint32_t type_components(std::string_view type) {
    constexpr std::array<std::pair<std::string_view, std::uint32_t>, 7> TYPES = {{{"SCALAR", 1},
                                                                                  {"VEC2", 2},
                                                                                  {"VEC3", 3},
                                                                                  {"VEC4", 4},
                                                                                  {"MAT2", 4},
                                                                                  {"MAT3", 9},
                                                                                  {"MAT4", 16}}};
    for (const auto& [name, components] : TYPES) {
        if (name == type) {
            return components;
        }
    }
    return 0;
}

// One component, little-endian, as a double (normalized integers per the glTF 2.0 spec).
double read_component(const char* p, std::uint32_t type, bool normalized) {
    const auto u8 = [&](int k) {
        return static_cast<std::uint32_t>(static_cast<unsigned char>(p[k]));
    };
    switch (type) {
        case BYTE: {
            const auto v = static_cast<std::int8_t>(u8(0));
            return normalized ? std::max(v / 127.0, -1.0) : v;
        }
        case UNSIGNED_BYTE:
            return normalized ? u8(0) / 255.0 : u8(0);
        case SHORT: {
            const auto v =
                static_cast<std::int16_t>(static_cast<std::uint16_t>(u8(0) | u8(1) << 8));
            return normalized ? std::max(v / 32767.0, -1.0) : v;
        }
        case UNSIGNED_SHORT: {
            const std::uint32_t v = u8(0) | u8(1) << 8;
            return normalized ? v / 65535.0 : v;
        }
        case UNSIGNED_INT:
            return u8(0) | u8(1) << 8 | u8(2) << 16 | u8(3) << 24;
        case FLOAT:
            return std::bit_cast<float>(u8(0) | u8(1) << 8 | u8(2) << 16 | u8(3) << 24);
        default:
            return 0.0;
    }
}

// Column-major, as glTF writes it: m[column * 4 + row].
using Mat4 = std::array<double, 16>;
constexpr Mat4 IDENTITY = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

Mat4 multiply(const Mat4& a, const Mat4& b) {
    Mat4 c{};
    for (int column = 0; column < 4; ++column) {
        for (int row = 0; row < 4; ++row) {
            double sum = 0.0;
            for (int k = 0; k < 4; ++k) {
                sum += a[k * 4 + row] * b[column * 4 + k];
            }
            c[column * 4 + row] = sum;
        }
    }
    return c;
}

Vec3 apply(const Mat4& m, const Vec3& p) {
    return {m[0] * p.x + m[4] * p.y + m[8] * p.z + m[12],
            m[1] * p.x + m[5] * p.y + m[9] * p.z + m[13],
            m[2] * p.x + m[6] * p.y + m[10] * p.z + m[14]};
}

// Where an accessor's elements are, checked against the bytes that exist.
struct AccessorData {
    std::string_view bytes;  // from the first element on; empty without a bufferView (zeros)
    std::uint64_t count = 0;
    std::uint64_t stride = 0;
    std::uint32_t component_type = 0;
    std::uint32_t components = 0;
    bool normalized = false;
    // Sparse substitution: `sparse_count` (index, element) pairs, tightly packed.
    std::uint64_t sparse_count = 0;
    std::string_view sparse_indices;
    std::uint32_t sparse_index_type = 0;
    std::string_view sparse_values;
};

// Every element's components as doubles (count * components values); the caller has bounded
// count against the output limit.
void decode(const AccessorData& a, std::vector<double>& out) {
    const std::size_t components = a.components;
    const std::uint64_t size = component_size(a.component_type);
    out.assign(static_cast<std::size_t>(a.count) * components, 0.0);
    if (!a.bytes.empty()) {
        for (std::size_t i = 0; i < a.count; ++i) {
            const char* element = a.bytes.data() + i * a.stride;
            for (std::size_t k = 0; k < components; ++k) {
                out[i * components + k] =
                    read_component(element + k * size, a.component_type, a.normalized);
            }
        }
    }
    const std::uint64_t index_size = component_size(a.sparse_index_type);
    for (std::size_t j = 0; j < a.sparse_count; ++j) {
        const auto target = static_cast<std::size_t>(
            read_component(a.sparse_indices.data() + j * index_size, a.sparse_index_type, false));
        const char* element = a.sparse_values.data() + j * components * size;
        for (std::size_t k = 0; k < components; ++k) {
            out[target * components + k] =
                read_component(element + k * size, a.component_type, a.normalized);
        }
    }
}

struct View {
    std::string_view bytes;  // exactly byteLength bytes
    std::optional<std::uint64_t> stride;
};

struct DecodedMesh {
    std::vector<Vec3> positions;
    std::vector<TriangleIndices> triangles;
};

class GltfReader {
  public:
    GltfReader(const std::string& name, std::string_view data, bool binary,
               const GltfBufferLoader& load_buffer)
        : m_name(name), m_data(data), m_binary(binary), m_load(load_buffer) {}

    StatusOr<TriangleMesh> read() {
        if (Status s = read_container(); !s.ok()) {
            return s;
        }
        if (Status s = parse_json(); !s.ok()) {
            return s;
        }
        if (Status s = check_asset(); !s.ok()) {
            return s;
        }
        if (Status s = top_level_arrays(); !s.ok()) {
            return s;
        }
        if (Status s = check_forest(); !s.ok()) {
            return s;
        }
        std::vector<std::uint64_t> roots;
        if (Status s = scene_roots(roots); !s.ok()) {
            return s;
        }
        if (Status s = traverse(roots); !s.ok()) {
            return s;
        }
        return std::move(m_out);
    }

  private:
    Status error(const std::string& problem) const {
        return invalid_argument("mesh file '" + m_name + "': " + problem);
    }

    // ---- container and document

    Status read_container() {
        if (!m_binary) {
            m_json_text = m_data;
            return {};
        }
        const auto glb_error = [&](const std::string& problem) {
            return error("binary glTF: " + problem);
        };
        if (m_data.size() < GLB_HEADER) {
            return glb_error("the file is " + std::to_string(m_data.size()) +
                             " bytes, shorter than the 12-byte header");
        }
        if (little_u32(m_data, 0) != GLB_MAGIC) {
            return glb_error("the file does not start with 'glTF'");
        }
        const std::uint32_t version = little_u32(m_data, 4);
        if (version == 1) {
            return error("glTF 1.0 is not supported, convert it to glTF 2.0");
        }
        if (version != 2) {
            return glb_error("container version " + std::to_string(version) +
                             ", only version 2 is supported");
        }
        const std::uint64_t length = little_u32(m_data, 8);
        if (length > m_data.size()) {
            return glb_error("the header declares " + std::to_string(length) +
                             " bytes, the file holds " + std::to_string(m_data.size()));
        }
        if (length < GLB_HEADER) {
            return glb_error("the header declares " + std::to_string(length) +
                             " bytes, less than the header itself");
        }
        const std::string_view glb = m_data.substr(0, static_cast<std::size_t>(length));
        std::uint64_t at = GLB_HEADER;
        std::size_t chunks = 0;
        while (at < length) {
            if (length - at < CHUNK_HEADER) {
                return glb_error(std::to_string(length - at) + " bytes at byte " +
                                 std::to_string(at) + ", too few for a chunk header");
            }
            const std::uint64_t chunk = little_u32(glb, at);
            const std::uint32_t type = little_u32(glb, at + 4);
            if (chunk > length - at - CHUNK_HEADER) {
                return glb_error("the chunk at byte " + std::to_string(at) + " declares " +
                                 std::to_string(chunk) + " bytes, " +
                                 std::to_string(length - at - CHUNK_HEADER) + " follow it");
            }
            const std::string_view payload = glb.substr(static_cast<std::size_t>(at + CHUNK_HEADER),
                                                        static_cast<std::size_t>(chunk));
            if (chunks == 0) {
                if (type != CHUNK_JSON) {
                    return glb_error("the first chunk has type " + hex32(type) +
                                     ", not JSON (0x4e4f534a)");
                }
                m_json_text = payload;
            } else if (chunks == 1 && type == CHUNK_BIN) {
                m_bin = payload;
            }  // chunks of other types are ignored, as the spec asks
            ++chunks;
            at += CHUNK_HEADER + chunk;
            at = std::min(length, (at + 3) / 4 * 4);  // chunks are padded to 4 bytes
        }
        if (chunks == 0) {
            return glb_error("no JSON chunk");
        }
        // The JSON chunk is padded with spaces; some writers pad with NULs.
        while (!m_json_text.empty() && m_json_text.back() == '\0') {
            m_json_text.remove_suffix(1);
        }
        return {};
    }

    Status parse_json() {
        const std::string what = m_binary ? "the JSON chunk" : "the glTF JSON";
        m_doc = Json::parse(m_json_text.begin(), m_json_text.end(), nullptr, false);
        if (m_doc.is_discarded()) {
            if (const std::size_t bad = invalid_utf8_at(m_json_text);
                bad != std::string_view::npos) {
                return error(what + " is not valid UTF-8 (byte " + std::to_string(bad) +
                             " of the JSON)");
            }
            ErrorOnlySax sax;
            Json::sax_parse(m_json_text.begin(), m_json_text.end(), &sax,
                            nlohmann::detail::input_format_t::json, true);
            return error(what + " is not valid JSON: " + printable(sax.message, 160));
        }
        if (!m_doc.is_object()) {
            return error(what + " is " + describe(m_doc) + ", not a JSON object");
        }
        return {};
    }

    Status check_asset() {
        const Json* asset = find(m_doc, "asset");
        const Json* version =
            asset != nullptr && asset->is_object() ? find(*asset, "version") : nullptr;
        const Json* meshes = find(m_doc, "meshes");
        const bool old_style = meshes != nullptr && meshes->is_object();  // glTF 1.0: dictionaries
        if (version == nullptr || !version->is_string()) {
            if (old_style) {
                return error("glTF 1.0 is not supported, convert it to glTF 2.0");
            }
            return error("no asset.version string (glTF 2.0 requires one)");
        }
        const auto& text = version->get_ref<const std::string&>();
        if (text.starts_with("1.") || text == "1") {
            return error("glTF 1.0 is not supported, convert it to glTF 2.0");
        }
        if (!text.starts_with("2.")) {
            return error("glTF version '" + printable(text) + "' is not supported (2.x only)");
        }
        if (const Json* used = find(m_doc, "extensionsUsed"); used != nullptr) {
            if (!used->is_array()) {
                return error("'extensionsUsed' must be an array, found " + describe(*used));
            }
            for (const Json& extension : *used) {
                if (extension.is_string() &&
                    extension.get_ref<const std::string&>() == "KHR_mesh_quantization") {
                    m_quantization = true;
                }
            }
        }
        if (const Json* required = find(m_doc, "extensionsRequired"); required != nullptr) {
            if (!required->is_array()) {
                return error("'extensionsRequired' must be an array, found " + describe(*required));
            }
            for (const Json& extension : *required) {
                if (!extension.is_string()) {
                    return error("'extensionsRequired' holds " + describe(extension) +
                                 ", not an extension name");
                }
                const auto& name = extension.get_ref<const std::string&>();
                if (!is_supported_required_extension(name)) {
                    return error("the file requires glTF extension '" + printable(name, 80) +
                                 "', which this reader does not support");
                }
                if (name == "KHR_mesh_quantization") {
                    m_quantization = true;
                }
            }
        }
        return {};
    }

    Status top_level_arrays() {
        const std::array<std::pair<const char*, const Json**>, 6> arrays = {{
            {"accessors", &m_accessors},
            {"bufferViews", &m_views},
            {"buffers", &m_buffers},
            {"meshes", &m_meshes},
            {"nodes", &m_nodes},
            {"scenes", &m_scenes},
        }};
        for (const auto& [key, target] : arrays) {
            const Json* value = find(m_doc, key);
            if (value != nullptr && !value->is_array()) {
                return error("'" + std::string(key) + "' must be an array, found " +
                             describe(*value));
            }
            *target = value;
        }
        const std::size_t buffers = size(m_buffers);
        m_buffer_storage.resize(buffers);
        m_buffer_data.resize(buffers);
        m_buffer_loaded.assign(buffers, false);
        m_decoded.resize(size(m_meshes));
        return {};
    }

    static std::size_t size(const Json* array) { return array == nullptr ? 0 : array->size(); }

    // ---- JSON fields

    // An optional non-negative integer; `out` keeps its value (the default) when absent.
    Status uint_field(const Json& object, const char* key, const std::string& where,
                      std::uint64_t& out, bool required = false) const {
        const Json* value = find(object, key);
        if (value == nullptr) {
            return required ? error(where + ": no '" + key + "'") : Status{};
        }
        if (!to_uint(*value, out)) {
            return error(where + ": '" + key + "' must be a non-negative integer, found " +
                         describe(*value));
        }
        return {};
    }

    // Element `index` of a top-level array, which must be an object. `what` is its singular
    // name ("accessor"), `user` who refers to it.
    Status element(const Json* array, const char* what, std::uint64_t index,
                   const std::string& user, const Json*& out) const {
        const std::size_t n = size(array);
        if (index >= n) {
            return error(user + " refers to " + what + " " + std::to_string(index) +
                         ", out of range (the file has " + std::to_string(n) + " " + what + "s)");
        }
        out = &(*array)[static_cast<std::size_t>(index)];
        if (!out->is_object()) {
            return error(std::string(what) + " " + std::to_string(index) +
                         " must be an object, found " + describe(*out));
        }
        return {};
    }

    // Numbers of a transform property: `n` finite numbers.
    Status numbers(const Json& object, const char* key, std::size_t n, const std::string& where,
                   double* out, bool& present) const {
        const Json* value = find(object, key);
        present = value != nullptr;
        if (!present) {
            return {};
        }
        if (!value->is_array() || value->size() != n) {
            return error(where + ": '" + key + "' must be an array of " + std::to_string(n) +
                         " numbers, found " +
                         (value->is_array() ? "an array of " + std::to_string(value->size())
                                            : describe(*value)));
        }
        for (std::size_t i = 0; i < n; ++i) {
            const Json& x = (*value)[i];
            if (!x.is_number()) {
                return error(where + ": '" + key + "'[" + std::to_string(i) +
                             "] must be a number, found " + describe(x));
            }
            out[i] = x.get<double>();
            if (!std::isfinite(out[i])) {
                return error(where + ": '" + key + "'[" + std::to_string(i) + "] is not finite");
            }
        }
        return {};
    }

    // ---- buffers, views, accessors

    Status buffer(std::uint64_t index, const std::string& user, std::string_view& out) {
        const Json* object = nullptr;
        if (Status s = element(m_buffers, "buffer", index, user, object); !s.ok()) {
            return s;
        }
        const std::string where = "buffer " + std::to_string(index);
        std::uint64_t length = 0;
        if (Status s = uint_field(*object, "byteLength", where, length, true); !s.ok()) {
            return s;
        }
        if (length == 0) {
            return error(where + ": byteLength is 0");
        }
        const auto i = static_cast<std::size_t>(index);
        if (!m_buffer_loaded[i]) {
            if (Status s = load(*object, index, where, length); !s.ok()) {
                return s;
            }
            m_buffer_loaded[i] = true;
        }
        out = m_buffer_data[i].substr(0, static_cast<std::size_t>(length));
        return {};
    }

    // Finds the bytes of a buffer once: the BIN chunk, a base64 data URI, or the loader's.
    Status load(const Json& object, std::uint64_t index, const std::string& where,
                std::uint64_t length) {
        const auto i = static_cast<std::size_t>(index);
        const Json* uri = find(object, "uri");
        std::string_view bytes;
        std::string source;
        if (uri == nullptr) {
            if (!m_bin || index != 0) {
                return error(where + " has no uri" +
                             (m_binary ? (index == 0 ? " and the file has no BIN chunk"
                                                     : ", and only buffer 0 may be the BIN chunk")
                                       : std::string(", and a .gltf has no BIN chunk")));
            }
            bytes = *m_bin;
            source = "the BIN chunk";
        } else {
            if (!uri->is_string()) {
                return error(where + ": 'uri' must be a string, found " + describe(*uri));
            }
            const auto& text = uri->get_ref<const std::string&>();
            std::string& storage = m_buffer_storage[i].emplace();
            if (text.starts_with("data:")) {
                const std::size_t comma = text.find(',');
                const std::string_view header =
                    std::string_view(text).substr(0, comma == std::string::npos ? 0 : comma);
                if (comma == std::string::npos || !header.ends_with(";base64")) {
                    return error(where + ": a data URI that is not base64 ('" + printable(text) +
                                 "')");
                }
                const std::string problem =
                    decode_base64(std::string_view(text).substr(comma + 1), storage);
                if (!problem.empty()) {
                    return error(where + ": invalid base64 in its data URI: " + problem);
                }
                source = "its data URI";
            } else {
                std::string decoded;
                const std::string problem = percent_decode(text, decoded);
                if (!problem.empty()) {
                    return error(where + ": invalid uri '" + printable(text) + "': " + problem);
                }
                StatusOr<std::string> loaded =
                    m_load ? m_load(decoded)
                           : StatusOr<std::string>(not_found("external buffers are not read"));
                if (!loaded.ok()) {
                    // The loader's message may name the file too: once is enough.
                    std::string_view reason = loaded.status().message();
                    if (const std::string prefix = "mesh file '" + m_name + "': ";
                        reason.starts_with(prefix)) {
                        reason.remove_prefix(prefix.size());
                    }
                    return Status(loaded.status().code(),
                                  "mesh file '" + m_name + "': " + where + " ('" +
                                      printable(decoded, 80) +
                                      "') cannot be loaded: " + std::string(reason));
                }
                storage = std::move(loaded).value();
                m_external_bytes += storage.size();
                source = "'" + printable(decoded, 80) + "'";
            }
            bytes = storage;
        }
        if (bytes.size() < length) {
            return error(where + " declares byteLength " + std::to_string(length) + ", " + source +
                         " holds " + std::to_string(bytes.size()) + " bytes");
        }
        m_buffer_data[i] = bytes;
        return {};
    }

    Status buffer_view(std::uint64_t index, const std::string& user, View& out) {
        const Json* object = nullptr;
        if (Status s = element(m_views, "bufferView", index, user, object); !s.ok()) {
            return s;
        }
        const std::string where = "bufferView " + std::to_string(index);
        std::uint64_t buffer_index = 0;
        std::uint64_t offset = 0;
        std::uint64_t length = 0;
        if (Status s = uint_field(*object, "buffer", where, buffer_index, true); !s.ok()) {
            return s;
        }
        if (Status s = uint_field(*object, "byteOffset", where, offset); !s.ok()) {
            return s;
        }
        if (Status s = uint_field(*object, "byteLength", where, length, true); !s.ok()) {
            return s;
        }
        if (length == 0) {
            return error(where + ": byteLength is 0");
        }
        if (find(*object, "byteStride") != nullptr) {
            std::uint64_t stride = 0;
            if (Status s = uint_field(*object, "byteStride", where, stride); !s.ok()) {
                return s;
            }
            if (stride < 4 || stride > 252 || stride % 4 != 0) {
                return error(where + ": byteStride " + std::to_string(stride) +
                             " (glTF allows multiples of 4 from 4 to 252)");
            }
            out.stride = stride;
        }
        std::string_view bytes;
        if (Status s = buffer(buffer_index, where, bytes); !s.ok()) {
            return s;
        }
        if (offset > bytes.size() || length > bytes.size() - offset) {
            return error(where + ": bytes " + std::to_string(offset) + " + " +
                         std::to_string(length) + " run past the end of buffer " +
                         std::to_string(buffer_index) + " (" + std::to_string(bytes.size()) +
                         " bytes)");
        }
        out.bytes =
            bytes.substr(static_cast<std::size_t>(offset), static_cast<std::size_t>(length));
        return {};
    }

    // Checks that `count` elements of `element_size` bytes, `stride` apart, from `offset` fit
    // in `available` bytes.
    static bool fits(std::uint64_t offset, std::uint64_t stride, std::uint64_t count,
                     std::uint64_t element_size, std::uint64_t available) {
        std::uint64_t span = 0;
        std::uint64_t end = 0;
        return count >= 1 && mul(stride, count - 1, span) && add(offset, span, end) &&
               add(end, element_size, end) && end <= available;
    }

    // Accessor `index` of type `expected_type`, with every byte it covers checked.
    Status accessor(std::uint64_t index, const std::string& user, std::string_view expected_type,
                    AccessorData& out) {
        const Json* object = nullptr;
        if (Status s = element(m_accessors, "accessor", index, user, object); !s.ok()) {
            return s;
        }
        const std::string where = "accessor " + std::to_string(index) + " (" + user + ")";
        const Json* type = find(*object, "type");
        if (type == nullptr || !type->is_string() ||
            type_components(type->get<std::string>()) == 0) {
            return error(where +
                         ": 'type' must be SCALAR, VEC2, VEC3, VEC4, MAT2, MAT3 or MAT4, found " +
                         (type == nullptr ? std::string("nothing") : describe(*type)));
        }
        if (type->get_ref<const std::string&>() != expected_type) {
            return error(where + ": type " + type->get<std::string>() + ", " +
                         std::string(expected_type) + " expected");
        }
        out.components = type_components(expected_type);
        std::uint64_t component_type = 0;
        if (Status s = uint_field(*object, "componentType", where, component_type, true); !s.ok()) {
            return s;
        }
        if (component_type > std::numeric_limits<std::uint32_t>::max() ||
            component_size(static_cast<std::uint32_t>(component_type)) == 0) {
            return error(where + ": componentType " + std::to_string(component_type) +
                         " is not a glTF component type");
        }
        out.component_type = static_cast<std::uint32_t>(component_type);
        if (Status s = uint_field(*object, "count", where, out.count, true); !s.ok()) {
            return s;
        }
        if (out.count == 0) {
            return error(where + ": count is 0");
        }
        std::uint64_t offset = 0;
        if (Status s = uint_field(*object, "byteOffset", where, offset); !s.ok()) {
            return s;
        }
        if (const Json* normalized = find(*object, "normalized"); normalized != nullptr) {
            if (!normalized->is_boolean()) {
                return error(where + ": 'normalized' must be true or false, found " +
                             describe(*normalized));
            }
            out.normalized = normalized->get<bool>();
        }
        const std::uint64_t element_size = component_size(out.component_type) * out.components;
        if (find(*object, "bufferView") != nullptr) {
            std::uint64_t view_index = 0;
            if (Status s = uint_field(*object, "bufferView", where, view_index); !s.ok()) {
                return s;
            }
            View view;
            if (Status s = buffer_view(view_index, where, view); !s.ok()) {
                return s;
            }
            out.stride = view.stride.value_or(element_size);
            if (out.stride < element_size) {
                return error("bufferView " + std::to_string(view_index) + ": byteStride " +
                             std::to_string(out.stride) + " is shorter than the elements of " +
                             where + " (" + std::to_string(element_size) + " bytes)");
            }
            if (!fits(offset, out.stride, out.count, element_size, view.bytes.size())) {
                return error(where + ": " + std::to_string(out.count) + " elements of " +
                             std::to_string(element_size) + " bytes, " +
                             std::to_string(out.stride) + " apart from byte " +
                             std::to_string(offset) + ", run past the end of bufferView " +
                             std::to_string(view_index) + " (" + std::to_string(view.bytes.size()) +
                             " bytes)");
            }
            out.bytes = view.bytes.substr(static_cast<std::size_t>(offset));
        } else if (offset != 0) {
            return error(where + ": byteOffset " + std::to_string(offset) +
                         " without a bufferView");
        }
        if (const Json* sparse = find(*object, "sparse"); sparse != nullptr) {
            if (Status s = sparse_part(*sparse, where, element_size, out); !s.ok()) {
                return s;
            }
        }
        return {};
    }

    Status sparse_part(const Json& sparse, const std::string& where, std::uint64_t element_size,
                       AccessorData& out) {
        const std::string sparse_where = where + ", sparse";
        if (!sparse.is_object()) {
            return error(sparse_where + " must be an object, found " + describe(sparse));
        }
        if (Status s = uint_field(sparse, "count", sparse_where, out.sparse_count, true); !s.ok()) {
            return s;
        }
        if (out.sparse_count == 0 || out.sparse_count > out.count) {
            return error(sparse_where + ": count " + std::to_string(out.sparse_count) +
                         " (1 to the accessor's " + std::to_string(out.count) + ")");
        }
        const Json* indices = find(sparse, "indices");
        const Json* values = find(sparse, "values");
        if (indices == nullptr || !indices->is_object() || values == nullptr ||
            !values->is_object()) {
            return error(sparse_where + ": 'indices' and 'values' must be objects");
        }
        // The indices.
        std::uint64_t index_type = 0;
        if (Status s =
                uint_field(*indices, "componentType", sparse_where + ".indices", index_type, true);
            !s.ok()) {
            return s;
        }
        if (index_type != UNSIGNED_BYTE && index_type != UNSIGNED_SHORT &&
            index_type != UNSIGNED_INT) {
            return error(sparse_where + ".indices: componentType " + std::to_string(index_type) +
                         " (5121, 5123 or 5125 expected)");
        }
        out.sparse_index_type = static_cast<std::uint32_t>(index_type);
        if (Status s = sparse_bytes(*indices, sparse_where + ".indices", out.sparse_count,
                                    component_size(out.sparse_index_type), out.sparse_indices);
            !s.ok()) {
            return s;
        }
        if (Status s = sparse_bytes(*values, sparse_where + ".values", out.sparse_count,
                                    element_size, out.sparse_values);
            !s.ok()) {
            return s;
        }
        // Strictly increasing and within the accessor, before decode() writes through them.
        const std::uint64_t index_size = component_size(out.sparse_index_type);
        std::uint64_t previous = 0;
        for (std::uint64_t j = 0; j < out.sparse_count; ++j) {
            const auto target = static_cast<std::uint64_t>(read_component(
                out.sparse_indices.data() + j * index_size, out.sparse_index_type, false));
            if (target >= out.count || (j > 0 && target <= previous)) {
                return error(sparse_where + ": index " + std::to_string(j) + " is " +
                             std::to_string(target) +
                             (target >= out.count
                                  ? ", out of range (" + std::to_string(out.count) + " elements)"
                                  : ", not above the previous one"));
            }
            previous = target;
        }
        return {};
    }

    // The tightly packed bytes of a sparse part (indices or values).
    Status sparse_bytes(const Json& part, const std::string& where, std::uint64_t count,
                        std::uint64_t element_size, std::string_view& out) {
        std::uint64_t view_index = 0;
        std::uint64_t offset = 0;
        if (Status s = uint_field(part, "bufferView", where, view_index, true); !s.ok()) {
            return s;
        }
        if (Status s = uint_field(part, "byteOffset", where, offset); !s.ok()) {
            return s;
        }
        View view;
        if (Status s = buffer_view(view_index, where, view); !s.ok()) {
            return s;
        }
        if (!fits(offset, element_size, count, element_size, view.bytes.size())) {
            return error(where + ": " + std::to_string(count) + " elements of " +
                         std::to_string(element_size) + " bytes from byte " +
                         std::to_string(offset) + " run past the end of bufferView " +
                         std::to_string(view_index) + " (" + std::to_string(view.bytes.size()) +
                         " bytes)");
        }
        out = view.bytes.substr(static_cast<std::size_t>(offset));
        return {};
    }

    // ---- scene graph

    // Every node has at most one parent and no node is its own ancestor.
    Status check_forest() {
        const std::size_t n = size(m_nodes);
        m_parent.assign(n, NO_PARENT);
        for (std::size_t i = 0; i < n; ++i) {
            const Json& node = (*m_nodes)[i];
            const std::string where = "node " + std::to_string(i);
            if (!node.is_object()) {
                return error(where + " must be an object, found " + describe(node));
            }
            const Json* children = find(node, "children");
            if (children == nullptr) {
                continue;
            }
            if (!children->is_array()) {
                return error(where + ": 'children' must be an array, found " + describe(*children));
            }
            for (const Json& child : *children) {
                std::uint64_t c = 0;
                if (!to_uint(child, c)) {
                    return error(where + ": 'children' holds " + describe(child) +
                                 ", not a node index");
                }
                if (c >= n) {
                    return error(where + " has child " + std::to_string(c) +
                                 ", out of range (the file has " + std::to_string(n) + " nodes)");
                }
                if (c == i) {
                    return error("nodes form a cycle: " + where + " is its own child");
                }
                if (m_parent[c] == i) {
                    return error(where + " lists child " + std::to_string(c) + " twice");
                }
                if (m_parent[c] != NO_PARENT) {
                    return error("node " + std::to_string(c) + " has two parents, node " +
                                 std::to_string(m_parent[c]) + " and " + where +
                                 " (nodes must form trees)");
                }
                m_parent[c] = i;
            }
        }
        // With one parent each, a node whose chain of parents never ends at a root is on or
        // below a cycle.
        std::vector<std::uint8_t> state(n, 0);  // 0 unknown, 1 reaches a root, 2 being walked
        std::vector<std::size_t> chain;
        for (std::size_t i = 0; i < n; ++i) {
            chain.clear();
            std::size_t at = i;
            while (state[at] == 0 && m_parent[at] != NO_PARENT) {
                state[at] = 2;
                chain.push_back(at);
                at = static_cast<std::size_t>(m_parent[at]);
            }
            if (state[at] == 2) {
                return error("nodes form a cycle through node " + std::to_string(at) +
                             " (nodes must form trees)");
            }
            state[at] = 1;
            for (const std::size_t k : chain) {
                state[k] = 1;
            }
        }
        return {};
    }

    Status scene_roots(std::vector<std::uint64_t>& roots) {
        const std::size_t n = size(m_nodes);
        std::optional<std::uint64_t> scene;
        if (find(m_doc, "scene") != nullptr) {
            std::uint64_t index = 0;
            if (Status s = uint_field(m_doc, "scene", "the document", index); !s.ok()) {
                return s;
            }
            if (index >= size(m_scenes)) {
                return error("'scene' is " + std::to_string(index) +
                             ", out of range (the file has " + std::to_string(size(m_scenes)) +
                             " scenes)");
            }
            scene = index;
        } else if (size(m_scenes) > 0) {
            scene = 0;
        }
        if (!scene) {
            for (std::size_t i = 0; i < n; ++i) {
                if (m_parent[i] == NO_PARENT) {
                    roots.push_back(i);
                }
            }
            return {};
        }
        const Json& object = (*m_scenes)[static_cast<std::size_t>(*scene)];
        const std::string where = "scene " + std::to_string(*scene);
        if (!object.is_object()) {
            return error(where + " must be an object, found " + describe(object));
        }
        const Json* nodes = find(object, "nodes");
        if (nodes == nullptr) {
            return {};
        }
        if (!nodes->is_array()) {
            return error(where + ": 'nodes' must be an array, found " + describe(*nodes));
        }
        std::vector<bool> listed(n, false);
        for (const Json& node : *nodes) {
            std::uint64_t i = 0;
            if (!to_uint(node, i)) {
                return error(where + ": 'nodes' holds " + describe(node) + ", not a node index");
            }
            if (i >= n) {
                return error(where + " lists node " + std::to_string(i) +
                             ", out of range (the file has " + std::to_string(n) + " nodes)");
            }
            if (listed[i]) {
                return error(where + " lists node " + std::to_string(i) + " twice");
            }
            if (m_parent[i] != NO_PARENT) {
                return error(where + " lists node " + std::to_string(i) +
                             ", which is a child of node " + std::to_string(m_parent[i]) +
                             " (a scene lists root nodes only)");
            }
            listed[i] = true;
            roots.push_back(i);
        }
        return {};
    }

    Status local_transform(const Json& node, const std::string& where, Mat4& out) const {
        bool present = false;
        if (Status s = numbers(node, "matrix", 16, where, out.data(), present); !s.ok()) {
            return s;
        }
        if (present) {
            return {};  // the spec forbids TRS beside a matrix; the matrix wins
        }
        std::array<double, 3> t = {0, 0, 0};
        std::array<double, 4> r = {0, 0, 0, 1};
        std::array<double, 3> s = {1, 1, 1};
        if (Status st = numbers(node, "translation", 3, where, t.data(), present); !st.ok()) {
            return st;
        }
        bool rotated = false;
        if (Status st = numbers(node, "rotation", 4, where, r.data(), rotated); !st.ok()) {
            return st;
        }
        if (Status st = numbers(node, "scale", 3, where, s.data(), present); !st.ok()) {
            return st;
        }
        if (rotated) {
            const double norm = std::sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3]);
            if (!(norm > 0.0) || !std::isfinite(norm)) {
                return error(where + ": 'rotation' is not a usable quaternion (length " +
                             std::to_string(norm) + ")");
            }
            if (norm != 1.0) {
                for (double& c : r) {
                    c /= norm;
                }
            }
        }
        const double x = r[0];
        const double y = r[1];
        const double z = r[2];
        const double w = r[3];
        // Rows of the rotation matrix of the unit quaternion (x, y, z, w).
        const std::array<std::array<double, 3>, 3> rotation = {{
            {1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)},
            {2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)},
            {2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)},
        }};
        out = IDENTITY;
        for (int column = 0; column < 3; ++column) {
            for (int row = 0; row < 3; ++row) {
                out[column * 4 + row] = rotation[row][column] * s[column];
            }
            out[12 + column] = t[column];
        }
        return {};
    }

    // Depth first from each root, children in order; each node's world transform in double.
    Status traverse(const std::vector<std::uint64_t>& roots) {
        std::vector<Mat4> world(size(m_nodes), IDENTITY);
        std::vector<std::uint64_t> stack(roots.rbegin(), roots.rend());
        while (!stack.empty()) {
            const auto i = static_cast<std::size_t>(stack.back());
            stack.pop_back();
            const Json& node = (*m_nodes)[i];
            const std::string where = "node " + std::to_string(i);
            Mat4 local = IDENTITY;
            if (Status s = local_transform(node, where, local); !s.ok()) {
                return s;
            }
            world[i] = m_parent[i] == NO_PARENT
                           ? local
                           : multiply(world[static_cast<std::size_t>(m_parent[i])], local);
            if (find(node, "mesh") != nullptr) {
                std::uint64_t mesh = 0;
                if (Status s = uint_field(node, "mesh", where, mesh); !s.ok()) {
                    return s;
                }
                if (mesh >= size(m_meshes)) {
                    return error(where + " refers to mesh " + std::to_string(mesh) +
                                 ", out of range (the file has " + std::to_string(size(m_meshes)) +
                                 " meshes)");
                }
                if (Status s = instance(mesh, i, world[i]); !s.ok()) {
                    return s;
                }
            }
            if (const Json* children = find(node, "children"); children != nullptr) {
                for (auto it = children->rbegin(); it != children->rend(); ++it) {
                    std::uint64_t c = 0;
                    to_uint(*it, c);  // checked by check_forest
                    stack.push_back(c);
                }
            }
        }
        return {};
    }

    // ---- meshes

    std::uint64_t output_limit() const {
        return std::max(MIN_OUTPUT_LIMIT,
                        OUTPUT_PER_INPUT_BYTE * (std::uint64_t{m_data.size()} + m_external_bytes));
    }

    // `vertices` and `triangles`: what the output would hold.
    Status check_output(std::uint64_t vertices, std::uint64_t triangles, std::uint64_t mesh,
                        std::size_t node) const {
        const std::uint64_t limit = output_limit();
        const std::string at =
            " (at mesh " + std::to_string(mesh) + " of node " + std::to_string(node) + ")";
        if (vertices > MAX_VERTICES) {
            return error("the scene has more than " + std::to_string(MAX_VERTICES) +
                         " vertices, more than 32-bit indices address" + at);
        }
        if (vertices > limit || triangles > limit) {
            return error("the scene would produce more than " + std::to_string(limit) + " " +
                         (vertices > limit ? "vertices" : "triangles") + at +
                         ", the limit for a file of " + std::to_string(m_data.size()) + " bytes" +
                         (m_external_bytes > 0
                              ? " with " + std::to_string(m_external_bytes) + " bytes of buffers"
                              : std::string()));
        }
        return {};
    }

    Status instance(std::uint64_t mesh, std::size_t node, const Mat4& world) {
        auto& decoded = m_decoded[static_cast<std::size_t>(mesh)];
        if (!decoded) {
            DecodedMesh fresh;
            if (Status s = decode_mesh(mesh, node, fresh); !s.ok()) {
                return s;
            }
            decoded = std::move(fresh);
        }
        if (Status s = check_output(m_out.vertices.size() + decoded->positions.size(),
                                    m_out.triangles.size() + decoded->triangles.size(), mesh, node);
            !s.ok()) {
            return s;
        }
        const auto base = static_cast<std::uint32_t>(m_out.vertices.size());
        if (world == IDENTITY) {
            m_out.vertices.insert(m_out.vertices.end(), decoded->positions.begin(),
                                  decoded->positions.end());
        } else {
            for (const Vec3& p : decoded->positions) {
                m_out.vertices.push_back(apply(world, p));
            }
        }
        for (const TriangleIndices& t : decoded->triangles) {
            m_out.triangles.push_back({base + t[0], base + t[1], base + t[2]});
        }
        return {};
    }

    Status decode_mesh(std::uint64_t m, std::size_t node, DecodedMesh& out) {
        const Json& mesh = (*m_meshes)[static_cast<std::size_t>(m)];
        const std::string mesh_where = "mesh " + std::to_string(m);
        if (!mesh.is_object()) {
            return error(mesh_where + " must be an object, found " + describe(mesh));
        }
        const Json* primitives = find(mesh, "primitives");
        if (primitives == nullptr || !primitives->is_array()) {
            return error(mesh_where + ": 'primitives' must be an array, found " +
                         (primitives == nullptr ? std::string("nothing") : describe(*primitives)));
        }
        // Primitives sharing a POSITION accessor share its vertices.
        std::map<std::uint64_t, std::uint32_t> position_base;
        std::vector<double> values;
        for (std::size_t p = 0; p < primitives->size(); ++p) {
            const Json& primitive = (*primitives)[p];
            const std::string where = mesh_where + ", primitive " + std::to_string(p);
            if (!primitive.is_object()) {
                return error(where + " must be an object, found " + describe(primitive));
            }
            std::uint64_t mode = TRIANGLES;
            if (Status s = uint_field(primitive, "mode", where, mode); !s.ok()) {
                return s;
            }
            if (mode < TRIANGLES) {
                continue;  // points and lines
            }
            if (mode > TRIANGLE_FAN) {
                return error(where + ": mode " + std::to_string(mode) +
                             " is not a glTF primitive mode (0 to 6)");
            }
            const Json* attributes = find(primitive, "attributes");
            if (attributes == nullptr || !attributes->is_object()) {
                return error(
                    where + ": 'attributes' must be an object, found " +
                    (attributes == nullptr ? std::string("nothing") : describe(*attributes)));
            }
            if (find(*attributes, "POSITION") == nullptr) {
                continue;  // the spec lets a client skip a primitive without positions
            }
            std::uint64_t position_index = 0;
            if (Status s = uint_field(*attributes, "POSITION", where, position_index); !s.ok()) {
                return s;
            }
            AccessorData positions;
            if (Status s = accessor(position_index, "POSITION of " + where, "VEC3", positions);
                !s.ok()) {
                return s;
            }
            const std::uint32_t type = positions.component_type;
            const bool quantized =
                type == BYTE || type == UNSIGNED_BYTE || type == SHORT || type == UNSIGNED_SHORT;
            if (type != FLOAT && !(quantized && m_quantization)) {
                return error("accessor " + std::to_string(position_index) + " (POSITION of " +
                             where + "): component type " + component_name(type) +
                             ", POSITION must be FLOAT (5126)" +
                             (quantized ? " unless the file uses KHR_mesh_quantization" : ""));
            }
            std::optional<AccessorData> indices;
            if (find(primitive, "indices") != nullptr) {
                std::uint64_t indices_index = 0;
                if (Status s = uint_field(primitive, "indices", where, indices_index); !s.ok()) {
                    return s;
                }
                AccessorData data;
                if (Status s = accessor(indices_index, "indices of " + where, "SCALAR", data);
                    !s.ok()) {
                    return s;
                }
                if (data.component_type != UNSIGNED_BYTE && data.component_type != UNSIGNED_SHORT &&
                    data.component_type != UNSIGNED_INT) {
                    return error("accessor " + std::to_string(indices_index) + " (indices of " +
                                 where + "): component type " +
                                 component_name(data.component_type) +
                                 ", indices must be UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT");
                }
                data.normalized = false;
                indices = data;
            }
            const std::uint64_t corners = indices ? indices->count : positions.count;
            if (mode == TRIANGLES && corners % 3 != 0) {
                return error(where + ": TRIANGLES with " + std::to_string(corners) + " " +
                             (indices ? "indices" : "vertices") + ", not a multiple of 3");
            }
            const std::uint64_t triangles =
                mode == TRIANGLES ? corners / 3 : (corners >= 3 ? corners - 2 : 0);
            if (triangles == 0) {
                continue;  // a strip or fan of fewer than 3 vertices
            }
            const auto shared = position_base.find(position_index);
            const std::uint64_t new_vertices = shared == position_base.end() ? positions.count : 0;
            if (Status s = check_output(m_out.vertices.size() + out.positions.size() + new_vertices,
                                        m_out.triangles.size() + out.triangles.size() + triangles,
                                        m, node);
                !s.ok()) {
                return s;
            }
            std::uint32_t base = 0;
            if (shared != position_base.end()) {
                base = shared->second;
            } else {
                base = static_cast<std::uint32_t>(out.positions.size());
                decode(positions, values);
                for (std::size_t v = 0; v < positions.count; ++v) {
                    out.positions.push_back({values[3 * v], values[3 * v + 1], values[3 * v + 2]});
                }
                position_base.emplace(position_index, base);
            }
            std::vector<std::uint32_t> corner(static_cast<std::size_t>(corners));
            if (indices) {
                decode(*indices, values);
                for (std::size_t k = 0; k < corners; ++k) {
                    const double value = values[k];
                    if (value >= static_cast<double>(positions.count)) {
                        return error(where + ": index " + std::to_string(k) + " is " +
                                     std::to_string(static_cast<std::uint64_t>(value)) +
                                     ", out of range (" + std::to_string(positions.count) +
                                     " vertices)");
                    }
                    corner[k] = static_cast<std::uint32_t>(value);
                }
            } else {
                for (std::size_t k = 0; k < corners; ++k) {
                    corner[k] = static_cast<std::uint32_t>(k);
                }
            }
            for (std::size_t t = 0; t < triangles; ++t) {
                TriangleIndices tri{};
                if (mode == TRIANGLES) {
                    tri = {corner[3 * t], corner[3 * t + 1], corner[3 * t + 2]};
                } else if (mode == TRIANGLE_STRIP) {
                    tri = {corner[t], corner[t + 1 + t % 2], corner[t + 2 - t % 2]};
                } else {
                    tri = {corner[t + 1], corner[t + 2], corner[0]};
                }
                out.triangles.push_back({base + tri[0], base + tri[1], base + tri[2]});
            }
        }
        return {};
    }

    static constexpr std::uint64_t NO_PARENT = std::numeric_limits<std::uint64_t>::max();

    const std::string& m_name;
    std::string_view m_data;
    bool m_binary;
    const GltfBufferLoader& m_load;

    std::string_view m_json_text;
    std::optional<std::string_view> m_bin;
    Json m_doc;
    bool m_quantization = false;
    const Json* m_accessors = nullptr;
    const Json* m_views = nullptr;
    const Json* m_buffers = nullptr;
    const Json* m_meshes = nullptr;
    const Json* m_nodes = nullptr;
    const Json* m_scenes = nullptr;

    // Buffers, each loaded at most once and only when an accessor needs it. m_buffer_storage
    // is sized once, so views into it stay valid.
    std::vector<std::optional<std::string>> m_buffer_storage;
    std::vector<std::string_view> m_buffer_data;
    std::vector<bool> m_buffer_loaded;
    std::uint64_t m_external_bytes = 0;

    std::vector<std::uint64_t> m_parent;
    std::vector<std::optional<DecodedMesh>> m_decoded;
    TriangleMesh m_out;
};

}  // namespace

StatusOr<TriangleMesh> read_gltf(const std::string& name, std::string_view data, bool binary,
                                 const GltfBufferLoader& load_buffer) {
    try {
        return GltfReader(name, data, binary, load_buffer).read();
    } catch (const std::exception& e) {
        // Every field is type-checked before it is read; this is the last line of defence.
        return Status(StatusCode::internal,
                      "mesh file '" + name + "': glTF reader failed: " + printable(e.what(), 200));
    }
}

}  // namespace proxima::detail
