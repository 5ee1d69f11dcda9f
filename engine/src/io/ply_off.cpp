#include "io/ply_off.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <optional>
#include <system_error>
#include <vector>

#include "io/text.hpp"

namespace proxima::detail {

namespace {

// Indices are 32-bit in TriangleMesh.
constexpr std::uint64_t MAX_VERTICES = std::numeric_limits<std::uint32_t>::max();

Status file_error(const std::string& path, const std::string& problem) {
    return invalid_argument("mesh file '" + path + "': " + problem);
}

bool is_space(char c) {
    return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f' || c == '\v';
}

std::string found(std::string_view token) {
    return token.empty() ? "found the end of the file" : "found '" + printable(token) + "'";
}

std::string number(double value) {
    std::array<char, 32> buf{};
    std::snprintf(buf.data(), buf.size(), "%.17g", value);
    return buf.data();
}

bool parse_count(std::string_view token, std::uint64_t& out) {
    if (!token.empty() && token[0] == '+') {
        token.remove_prefix(1);
    }
    if (token.empty() || token[0] == '-') {
        return false;
    }
    const char* last = token.data() + token.size();
    const auto [ptr, ec] = std::from_chars(token.data(), last, out);
    return ec == std::errc{} && ptr == last;
}

// One polygon corner, read as a double because PLY allows any scalar type for indices (every
// integer PLY type converts exactly). Returns the problem, or an empty string when `value` is a
// valid index.
std::string index_problem(double value, std::uint64_t vertex_count, std::uint32_t& out) {
    if (!(value == std::floor(value))) {
        return "vertex index " + number(value) + ", not an integer";
    }
    if (value < 0.0) {
        return "negative vertex index " + number(value);
    }
    if (value >= static_cast<double>(vertex_count)) {
        return "vertex index " + number(value) + ", out of range (" + std::to_string(vertex_count) +
               " vertices)";
    }
    out = static_cast<std::uint32_t>(value);
    return {};
}

// Fan (v0, vi, vi+1) in order, so that triangle ids follow the file's polygon order.
void append_fan(const std::vector<std::uint32_t>& polygon, std::vector<TriangleIndices>& out) {
    for (std::size_t i = 1; i + 1 < polygon.size(); ++i) {
        out.push_back({polygon[0], polygon[i], polygon[i + 1]});
    }
}

// Whitespace-separated tokens over text, optionally with '#' comments to the end of the line.
class TextCursor {
  public:
    TextCursor(std::string_view data, std::size_t pos, bool hash_comments)
        : m_data(data), m_pos(pos), m_hash_comments(hash_comments) {}

    // The next token, empty at the end of the data.
    std::string_view next() {
        skip_blank(true);
        const std::size_t start = m_pos;
        while (m_pos < m_data.size() && !is_space(m_data[m_pos]) &&
               !(m_hash_comments && m_data[m_pos] == '#')) {
            ++m_pos;
        }
        return m_data.substr(start, m_pos - start);
    }

    // The next token on the current line, empty at a newline, a comment or the end.
    std::string_view next_on_line() {
        skip_blank(false);
        if (m_pos >= m_data.size() || m_data[m_pos] == '\n' ||
            (m_hash_comments && m_data[m_pos] == '#')) {
            return {};
        }
        return next();
    }

    // Moves past the next newline: whatever else is on the current line is ignored.
    void skip_line() {
        while (m_pos < m_data.size() && m_data[m_pos] != '\n') {
            ++m_pos;
        }
        if (m_pos < m_data.size()) {
            ++m_pos;
        }
    }

    // 1-based line of the current position (only computed for messages).
    std::size_t line() const {
        const auto end = m_data.begin() + static_cast<std::ptrdiff_t>(m_pos);
        return 1 + static_cast<std::size_t>(std::count(m_data.begin(), end, '\n'));
    }

    std::size_t remaining() const { return m_data.size() - m_pos; }

  private:
    void skip_blank(bool across_lines) {
        while (m_pos < m_data.size()) {
            const char c = m_data[m_pos];
            if (m_hash_comments && c == '#') {
                if (!across_lines) {
                    return;
                }
                while (m_pos < m_data.size() && m_data[m_pos] != '\n') {
                    ++m_pos;
                }
            } else if (c == '\n') {
                if (!across_lines) {
                    return;
                }
                ++m_pos;
            } else if (is_space(c)) {
                ++m_pos;
            } else {
                return;
            }
        }
    }

    std::string_view m_data;
    std::size_t m_pos;
    bool m_hash_comments;
};

// ---------------------------------------------------------------------------------------------
// OFF

enum class OffKeyword { not_off, plain, extra_columns, unsupported };

// [ST][C][N][4][n]OFF. Texture, colour and normal columns follow xyz on each vertex line and are
// ignored; homogeneous (4) and n-dimensional (n) vertices are not 3D points.
OffKeyword off_keyword(std::string_view word) {
    bool extra = false;
    bool unsupported = false;
    if (word.starts_with("ST")) {
        word.remove_prefix(2);
        extra = true;
    }
    if (word.starts_with("C")) {
        word.remove_prefix(1);
        extra = true;
    }
    if (word.starts_with("N")) {
        word.remove_prefix(1);
        extra = true;
    }
    if (word.starts_with("4")) {
        word.remove_prefix(1);
        unsupported = true;
    }
    if (word.starts_with("n")) {
        word.remove_prefix(1);
        unsupported = true;
    }
    if (word != "OFF") {
        return OffKeyword::not_off;
    }
    if (unsupported) {
        return OffKeyword::unsupported;
    }
    return extra ? OffKeyword::extra_columns : OffKeyword::plain;
}

// ---------------------------------------------------------------------------------------------
// PLY

enum class ScalarType : std::uint8_t {
    int8,
    uint8,
    int16,
    uint16,
    int32,
    uint32,
    float32,
    float64,
};

std::optional<ScalarType> scalar_type(std::string_view name) {
    struct Entry {
        std::string_view name;
        ScalarType type;
    };
    static constexpr std::array<Entry, 16> TYPES = {{
        {"char", ScalarType::int8},
        {"int8", ScalarType::int8},
        {"uchar", ScalarType::uint8},
        {"uint8", ScalarType::uint8},
        {"short", ScalarType::int16},
        {"int16", ScalarType::int16},
        {"ushort", ScalarType::uint16},
        {"uint16", ScalarType::uint16},
        {"int", ScalarType::int32},
        {"int32", ScalarType::int32},
        {"uint", ScalarType::uint32},
        {"uint32", ScalarType::uint32},
        {"float", ScalarType::float32},
        {"float32", ScalarType::float32},
        {"double", ScalarType::float64},
        {"float64", ScalarType::float64},
    }};
    for (const auto& entry : TYPES) {
        if (entry.name == name) {
            return entry.type;
        }
    }
    return std::nullopt;
}

std::size_t scalar_size(ScalarType type) {
    switch (type) {
        case ScalarType::int8:
        case ScalarType::uint8:
            return 1;
        case ScalarType::int16:
        case ScalarType::uint16:
            return 2;
        case ScalarType::int32:
        case ScalarType::uint32:
        case ScalarType::float32:
            return 4;
        case ScalarType::float64:
            return 8;
    }
    return 1;
}

template <class T>
double load_as_double(const unsigned char* p, bool swap) {
    std::array<unsigned char, sizeof(T)> bytes{};
    std::memcpy(bytes.data(), p, sizeof(T));
    if (swap) {
        std::reverse(bytes.begin(), bytes.end());
    }
    return static_cast<double>(std::bit_cast<T>(bytes));
}

double load_scalar(ScalarType type, const unsigned char* p, bool swap) {
    switch (type) {
        case ScalarType::int8:
            return load_as_double<std::int8_t>(p, swap);
        case ScalarType::uint8:
            return load_as_double<std::uint8_t>(p, swap);
        case ScalarType::int16:
            return load_as_double<std::int16_t>(p, swap);
        case ScalarType::uint16:
            return load_as_double<std::uint16_t>(p, swap);
        case ScalarType::int32:
            return load_as_double<std::int32_t>(p, swap);
        case ScalarType::uint32:
            return load_as_double<std::uint32_t>(p, swap);
        case ScalarType::float32:
            return load_as_double<float>(p, swap);
        case ScalarType::float64:
            return load_as_double<double>(p, swap);
    }
    return 0.0;
}

enum class PlyFormat { ascii, binary_little_endian, binary_big_endian };

struct PlyProperty {
    std::string name;
    ScalarType type = ScalarType::uint8;  // of the items, for a list
    bool is_list = false;
    ScalarType count_type = ScalarType::uint8;
};

struct PlyElement {
    std::string name;
    std::uint64_t count = 0;
    std::vector<PlyProperty> properties;
};

struct PlyHeader {
    PlyFormat format = PlyFormat::ascii;
    std::vector<PlyElement> elements;
    std::size_t body_offset = 0;
};

std::vector<std::string_view> split_words(std::string_view line) {
    std::vector<std::string_view> words;
    std::size_t pos = 0;
    while (pos < line.size()) {
        while (pos < line.size() && is_space(line[pos])) {
            ++pos;
        }
        const std::size_t start = pos;
        while (pos < line.size() && !is_space(line[pos])) {
            ++pos;
        }
        if (pos > start) {
            words.push_back(line.substr(start, pos - start));
        }
    }
    return words;
}

Status parse_ply_header(const std::string& path, std::string_view data, PlyHeader& header) {
    std::size_t pos = 0;
    std::size_t line_number = 0;
    bool have_format = false;
    while (true) {
        const std::size_t newline = data.find('\n', pos);
        if (newline == std::string_view::npos) {
            return file_error(path, line_number == 0 ? "not a PLY file (no complete first line)"
                                                     : "PLY header has no end_header line");
        }
        std::string_view line = data.substr(pos, newline - pos);
        pos = newline + 1;
        ++line_number;
        if (!line.empty() && line.back() == '\r') {
            line.remove_suffix(1);
        }
        const auto words = split_words(line);
        if (line_number == 1) {
            if (words.size() != 1 || words[0] != "ply") {
                return file_error(path, "not a PLY file (the first line is not 'ply')");
            }
            continue;
        }
        const std::string at = "PLY header line " + std::to_string(line_number) + ": ";
        if (words.empty()) {
            continue;
        }
        const std::string_view key = words[0];
        if (key == "comment" || key == "obj_info") {
            continue;
        }
        if (key == "format") {
            if (words.size() < 2) {
                return file_error(path, at + "expected 'format <ascii|binary_little_endian|"
                                             "binary_big_endian> 1.0'");
            }
            if (words[1] == "ascii") {
                header.format = PlyFormat::ascii;
            } else if (words[1] == "binary_little_endian") {
                header.format = PlyFormat::binary_little_endian;
            } else if (words[1] == "binary_big_endian") {
                header.format = PlyFormat::binary_big_endian;
            } else {
                return file_error(path, at + "unknown format '" + printable(words[1]) + "'");
            }
            have_format = true;
        } else if (key == "element") {
            std::uint64_t count = 0;
            if (words.size() != 3 || !parse_count(words[2], count)) {
                return file_error(path, at + "expected 'element <name> <count>', found '" +
                                            printable(line) + "'");
            }
            header.elements.push_back({std::string(words[1]), count, {}});
        } else if (key == "property") {
            if (header.elements.empty()) {
                return file_error(path, at + "property before any element");
            }
            PlyProperty property;
            if (words.size() == 5 && words[1] == "list") {
                const auto count_type = scalar_type(words[2]);
                const auto item_type = scalar_type(words[3]);
                if (!count_type || !item_type) {
                    return file_error(path,
                                      at + "unknown scalar type in '" + printable(line) + "'");
                }
                property = {std::string(words[4]), *item_type, true, *count_type};
            } else if (words.size() == 3 && words[1] != "list") {
                const auto type = scalar_type(words[1]);
                if (!type) {
                    return file_error(path,
                                      at + "unknown property type '" + printable(words[1]) + "'");
                }
                property = {std::string(words[2]), *type, false, ScalarType::uint8};
            } else {
                return file_error(path, at +
                                            "expected 'property <type> <name>' or 'property "
                                            "list <count type> <item type> <name>', found '" +
                                            printable(line) + "'");
            }
            header.elements.back().properties.push_back(std::move(property));
        } else if (key == "end_header") {
            break;
        } else {
            return file_error(path, at + "unknown keyword '" + printable(key) + "'");
        }
    }
    if (!have_format) {
        return file_error(path, "PLY header has no format line");
    }
    header.body_offset = pos;
    return {};
}

// What the reader does with one property's values.
enum class Use : std::uint8_t { skip, x, y, z, corners };

enum class ReadResult { ok, end, bad };

class BinarySource {
  public:
    BinarySource(std::string_view body, bool swap)
        : m_pos(reinterpret_cast<const unsigned char*>(body.data())),
          m_end(m_pos + body.size()),
          m_swap(swap) {}

    ReadResult scalar(ScalarType type, double& out) {
        const std::size_t size = scalar_size(type);
        if (static_cast<std::size_t>(m_end - m_pos) < size) {
            return ReadResult::end;
        }
        out = load_scalar(type, m_pos, m_swap);
        m_pos += size;
        return ReadResult::ok;
    }

    ReadResult skip(ScalarType type, std::uint64_t count) {
        const std::size_t size = scalar_size(type);
        if (count > static_cast<std::uint64_t>(m_end - m_pos) / size) {
            return ReadResult::end;
        }
        m_pos += count * size;
        return ReadResult::ok;
    }

    std::string bad_value() const { return {}; }

  private:
    const unsigned char* m_pos;
    const unsigned char* m_end;
    bool m_swap;
};

class TextSource {
  public:
    TextSource(std::string_view data, std::size_t pos) : m_in(data, pos, false) {}

    ReadResult scalar(ScalarType /*type*/, double& out) {
        const std::string_view token = m_in.next();
        if (token.empty()) {
            return ReadResult::end;
        }
        if (!parse_double(token, out)) {
            m_bad = token;
            return ReadResult::bad;
        }
        return ReadResult::ok;
    }

    // Skipped values are not parsed: an unknown property's text is no concern of ours.
    ReadResult skip(ScalarType /*type*/, std::uint64_t count) {
        for (std::uint64_t i = 0; i < count; ++i) {
            if (m_in.next().empty()) {
                return ReadResult::end;
            }
        }
        return ReadResult::ok;
    }

    std::string bad_value() const {
        return "line " + std::to_string(m_in.line()) + ": expected a number, found '" +
               printable(m_bad) + "'";
    }

  private:
    TextCursor m_in;
    std::string_view m_bad;
};

template <class Source>
Status decode_ply_body(const std::string& path, const PlyHeader& header,
                       const std::vector<std::vector<Use>>& uses, std::size_t vertex_element,
                       Source& source, TriangleMesh& mesh) {
    const std::uint64_t vertex_count = mesh.vertices.size();
    std::vector<std::uint32_t> polygon;
    for (std::size_t e = 0; e < header.elements.size(); ++e) {
        const PlyElement& element = header.elements[e];
        if (element.properties.empty()) {
            continue;  // nothing stored, whatever the count says
        }
        const bool is_vertex = e == vertex_element;
        for (std::uint64_t i = 0; i < element.count; ++i) {
            const auto item = [&] { return element.name + " " + std::to_string(i); };
            const auto failed = [&](ReadResult r) {
                if (r == ReadResult::end) {
                    return file_error(path, "file ends inside " + item());
                }
                return file_error(path, source.bad_value() + " (" + item() + ")");
            };
            Vec3 p;
            for (std::size_t k = 0; k < element.properties.size(); ++k) {
                const PlyProperty& property = element.properties[k];
                const Use use = uses[e][k];
                double value = 0.0;
                if (!property.is_list) {
                    const ReadResult r = use == Use::skip ? source.skip(property.type, 1)
                                                          : source.scalar(property.type, value);
                    if (r != ReadResult::ok) {
                        return failed(r);
                    }
                    if (use == Use::x) {
                        p.x = value;
                    } else if (use == Use::y) {
                        p.y = value;
                    } else if (use == Use::z) {
                        p.z = value;
                    }
                    continue;
                }
                double length = 0.0;
                if (const ReadResult r = source.scalar(property.count_type, length);
                    r != ReadResult::ok) {
                    return failed(r);
                }
                // Integer count types stop at 2^32-1; a float count beyond it is garbage.
                if (!(length >= 0.0 && length <= 4294967295.0 && length == std::floor(length))) {
                    return file_error(path, item() + " has a list '" + property.name +
                                                "' of length " + number(length));
                }
                const auto n = static_cast<std::uint64_t>(length);
                if (use != Use::corners) {
                    if (const ReadResult r = source.skip(property.type, n); r != ReadResult::ok) {
                        return failed(r);
                    }
                    continue;
                }
                if (n < 3) {
                    return file_error(path, item() + " has " + std::to_string(n) +
                                                " vertex indices (at least 3 are needed)");
                }
                polygon.clear();
                for (std::uint64_t j = 0; j < n; ++j) {
                    if (const ReadResult r = source.scalar(property.type, value);
                        r != ReadResult::ok) {
                        return failed(r);
                    }
                    std::uint32_t index = 0;
                    if (std::string problem = index_problem(value, vertex_count, index);
                        !problem.empty()) {
                        return file_error(path, item() + " has " + problem);
                    }
                    polygon.push_back(index);
                }
                append_fan(polygon, mesh.triangles);
            }
            if (is_vertex) {
                mesh.vertices[i] = p;
            }
        }
    }
    return {};
}

}  // namespace

NativeMeshFormat native_format_from_extension(const std::string& path) {
    std::string ext = std::filesystem::path(path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (ext == ".ply") {
        return NativeMeshFormat::ply;
    }
    if (ext == ".off") {
        return NativeMeshFormat::off;
    }
    return NativeMeshFormat::none;
}

NativeMeshFormat native_format_from_content(std::string_view head) {
    if (head.starts_with("ply\n") || head.starts_with("ply\r\n")) {
        return NativeMeshFormat::ply;
    }
    TextCursor in(head, 0, true);
    // Unsupported OFF variants are ours too: our message beats assimp's float reading of them.
    if (off_keyword(in.next()) != OffKeyword::not_off) {
        return NativeMeshFormat::off;
    }
    return NativeMeshFormat::none;
}

StatusOr<TriangleMesh> read_off(const std::string& path, std::string_view data) {
    if (data.empty()) {
        return file_error(path, "file is empty");
    }
    TextCursor in(data, 0, true);
    const std::string_view keyword = in.next();
    if (keyword.empty()) {
        return file_error(path, "file holds only blanks and comments, no OFF header");
    }
    OffKeyword kind = off_keyword(keyword);
    std::string_view token;
    std::uint64_t vertex_count = 0;
    if (kind == OffKeyword::not_off) {
        // The keyword is optional in Geomview's OFF: such files start with the counts.
        if (!parse_count(keyword, vertex_count)) {
            return file_error(
                path, "not an OFF file (it starts with '" + printable(keyword) + "', not OFF)");
        }
        kind = OffKeyword::plain;
        token = keyword;
    } else if (kind == OffKeyword::unsupported) {
        return file_error(path, "'" + printable(keyword) +
                                    "' (homogeneous or n-dimensional vertices) is not supported");
    } else {
        token = in.next_on_line();
        if (token == "BINARY") {
            return file_error(path, "binary OFF is not supported, only ASCII OFF");
        }
        if (token.empty()) {
            token = in.next();
        }
    }
    if (!parse_count(token, vertex_count)) {
        return file_error(path, "line " + std::to_string(in.line()) +
                                    ": expected the vertex count, " + found(token));
    }
    token = in.next();
    std::uint64_t face_count = 0;
    if (!parse_count(token, face_count)) {
        return file_error(path, "line " + std::to_string(in.line()) +
                                    ": expected the face count, " + found(token));
    }
    in.skip_line();  // the edge count, unused
    if (vertex_count > MAX_VERTICES) {
        return file_error(path, "header announces " + std::to_string(vertex_count) +
                                    " vertices, more than 2^32-1");
    }
    // At least "x y z" (5 bytes) per vertex and "3 a b c" (7 bytes) per face: a header that asks
    // for more than the file can hold is an error before anything is allocated.
    const std::uint64_t left = in.remaining();
    if (vertex_count > left / 5 || face_count > (left - vertex_count * 5) / 7) {
        return file_error(path, "header announces " + std::to_string(vertex_count) +
                                    " vertices and " + std::to_string(face_count) +
                                    " faces, more than the " + std::to_string(left) +
                                    " bytes after it can hold (truncated file?)");
    }
    const bool extra_columns = kind == OffKeyword::extra_columns;

    TriangleMesh mesh;
    mesh.vertices.reserve(vertex_count);
    for (std::uint64_t v = 0; v < vertex_count; ++v) {
        Vec3 p;
        for (int k = 0; k < 3; ++k) {
            token = in.next();
            if (token.empty()) {
                return file_error(path, "file ends inside vertex " + std::to_string(v) +
                                            " (the header announces " +
                                            std::to_string(vertex_count) + " vertices)");
            }
            if (!parse_double(token, p[k])) {
                return file_error(path, "line " + std::to_string(in.line()) + ": vertex " +
                                            std::to_string(v) + ": expected a number, " +
                                            found(token));
            }
        }
        if (extra_columns) {
            in.skip_line();  // colour, normal or texture columns
        }
        mesh.vertices.push_back(p);
    }

    mesh.triangles.reserve(face_count);
    std::vector<std::uint32_t> polygon;
    for (std::uint64_t f = 0; f < face_count; ++f) {
        const auto face = [f] { return "face " + std::to_string(f); };
        token = in.next();
        std::uint64_t n = 0;
        if (token.empty()) {
            return file_error(path, "file ends before " + face() + " (the header announces " +
                                        std::to_string(face_count) + " faces)");
        }
        if (!parse_count(token, n)) {
            return file_error(path, "line " + std::to_string(in.line()) + ": " + face() +
                                        ": expected its number of vertices, " + found(token));
        }
        if (n < 3) {
            return file_error(path, face() + " has " + std::to_string(n) +
                                        " vertex indices (at least 3 are needed)");
        }
        polygon.clear();
        for (std::uint64_t i = 0; i < n; ++i) {
            token = in.next();
            if (token.empty()) {
                return file_error(path, "file ends inside " + face());
            }
            double value = 0.0;
            if (!parse_double(token, value)) {
                return file_error(path, "line " + std::to_string(in.line()) + ": " + face() +
                                            ": expected a vertex index, " + found(token));
            }
            std::uint32_t index = 0;
            if (std::string problem = index_problem(value, vertex_count, index); !problem.empty()) {
                problem.insert(0, face() + " has ");
                return file_error(path, problem);
            }
            polygon.push_back(index);
        }
        in.skip_line();  // an optional face colour
        append_fan(polygon, mesh.triangles);
    }
    return mesh;
}

StatusOr<TriangleMesh> read_ply(const std::string& path, std::string_view data) {
    if (data.empty()) {
        return file_error(path, "file is empty");
    }
    PlyHeader header;
    if (Status s = parse_ply_header(path, data, header); !s.ok()) {
        return s;
    }

    // Find the vertex positions and the polygon lists; everything else is skipped.
    constexpr std::size_t NONE = std::numeric_limits<std::size_t>::max();
    std::size_t vertex_element = NONE;
    std::size_t face_element = NONE;
    std::vector<std::vector<Use>> uses(header.elements.size());
    for (std::size_t e = 0; e < header.elements.size(); ++e) {
        const PlyElement& element = header.elements[e];
        uses[e].assign(element.properties.size(), Use::skip);
        const auto find = [&](std::string_view name) {
            for (std::size_t k = 0; k < element.properties.size(); ++k) {
                if (element.properties[k].name == name) {
                    return k;
                }
            }
            return NONE;
        };
        if (element.name == "vertex") {
            if (vertex_element != NONE) {
                return file_error(path, "PLY header has more than one vertex element");
            }
            vertex_element = e;
            constexpr std::array<std::pair<std::string_view, Use>, 3> AXES = {
                {{"x", Use::x}, {"y", Use::y}, {"z", Use::z}}};
            for (const auto& [name, use] : AXES) {
                const std::size_t k = find(name);
                if (k == NONE) {
                    return file_error(path,
                                      "vertex element has no '" + std::string(name) + "' property");
                }
                if (element.properties[k].is_list) {
                    return file_error(path,
                                      "vertex property '" + std::string(name) + "' is a list");
                }
                uses[e][k] = use;
            }
        } else if (element.name == "face") {
            if (face_element != NONE) {
                return file_error(path, "PLY header has more than one face element");
            }
            face_element = e;
            std::size_t k = find("vertex_indices");
            if (k == NONE) {
                k = find("vertex_index");
            }
            if (k == NONE) {
                return file_error(path, "face element has no 'vertex_indices' list");
            }
            if (!element.properties[k].is_list) {
                return file_error(
                    path, "face property '" + element.properties[k].name + "' is not a list");
            }
            uses[e][k] = Use::corners;
        }
    }
    if (vertex_element == NONE) {
        return file_error(path, "PLY header has no vertex element");
    }
    if (face_element == NONE) {
        return file_error(path, "PLY header has no face element (a point cloud is not a mesh)");
    }
    const std::uint64_t vertex_count = header.elements[vertex_element].count;
    if (vertex_count > MAX_VERTICES) {
        return file_error(path, "header announces " + std::to_string(vertex_count) +
                                    " vertices, more than 2^32-1");
    }

    // Every element needs a minimum number of bytes (binary: its scalars and list lengths; ASCII:
    // one character per value plus a blank between values). Counts the body cannot hold are
    // errors before anything is allocated.
    const bool ascii = header.format == PlyFormat::ascii;
    const std::uint64_t body_size = data.size() - header.body_offset;
    std::uint64_t left = body_size;
    for (const PlyElement& element : header.elements) {
        std::uint64_t min_bytes = 0;
        if (ascii) {
            min_bytes = element.properties.empty() ? 0 : 2 * element.properties.size() - 1;
        } else {
            for (const PlyProperty& property : element.properties) {
                min_bytes += scalar_size(property.is_list ? property.count_type : property.type);
            }
        }
        if (min_bytes != 0 && element.count > left / min_bytes) {
            return file_error(path, "header announces " + std::to_string(element.count) + " " +
                                        element.name + " elements, more than the " +
                                        std::to_string(body_size) +
                                        " bytes after the header can hold (truncated file?)");
        }
        left -= element.count * min_bytes;
    }

    TriangleMesh mesh;
    mesh.vertices.resize(vertex_count);
    mesh.triangles.reserve(header.elements[face_element].count);
    Status status;
    if (ascii) {
        TextSource source(data, header.body_offset);
        status = decode_ply_body(path, header, uses, vertex_element, source, mesh);
    } else {
        const bool file_little = header.format == PlyFormat::binary_little_endian;
        const bool native_little = std::endian::native == std::endian::little;
        BinarySource source(data.substr(header.body_offset), file_little != native_little);
        status = decode_ply_body(path, header, uses, vertex_element, source, mesh);
    }
    if (!status.ok()) {
        return status;
    }
    return mesh;
}

}  // namespace proxima::detail
